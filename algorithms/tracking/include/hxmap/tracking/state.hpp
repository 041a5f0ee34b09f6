// Tracking's state over a recording: tracked, degraded or lost, each frame
// with the reason, decided from what the frame's tracking attempts gave.
// DESIGN: the pose never freezes while any attempt can follow the camera:
// frame-to-model ICP first; when it fails, frame-to-frame odometry against
// the previous frame (a degraded frame: the pose moves, the map does not);
// when both fail, relocalization against the keyframe database. Only a
// frame that the model confirms within the sensor's noise is fused.
#pragma once

#include <cstdint>
#include <deque>
#include <string>

#include "hxmap/tracking/icp.hpp"

namespace hxmap::alg {

enum class TrackingState : uint8_t { kTracked, kDegraded, kLost };
const char* trackingStateName(TrackingState state);

/// Where a frame's pose came from.
enum class PoseSource : uint8_t { kNone, kModel, kOdometry, kRelocalization, kGiven };
const char* poseSourceName(PoseSource source);

/// One frame's attempts, each null when it was not tried.
struct TrackingAttempts {
  bool enough_depth = true;
  const IcpResult* model = nullptr;     ///< frame-to-model ICP (its best initial guess)
  const IcpResult* odometry = nullptr;  ///< frame-to-frame fallback
  const IcpResult* relocalization = nullptr;  ///< a verified relocalization (ICP against the model at its pose)
};

struct TrackingDecision {
  TrackingState state = TrackingState::kLost;
  PoseSource source = PoseSource::kNone;
  bool fuse = false;   ///< the frame may be fused into the map
  std::string reason;  ///< why not tracked (empty when tracked)
};

/// Counts over a run.
struct TrackingCounts {
  uint64_t tracked = 0, degraded = 0, lost = 0;
  uint64_t relocalized = 0;         ///< frames whose pose came from relocalization
  uint64_t odometry_frames = 0;     ///< frames whose pose came from the frame-to-frame fallback
  uint64_t lost_episodes = 0;       ///< times the state entered lost
  uint64_t longest_lost_run = 0;    ///< most consecutive lost frames
};

class TrackingStateMachine {
 public:
  /// The first frame of a map: tracked by definition (it sets the frame).
  TrackingDecision start();
  /// A frame whose pose is given (evaluation against ground truth): tracked
  /// and fused.
  TrackingDecision given();
  /// The decision for the next frame from its attempts. Transitions:
  /// any state -> tracked when the model (or a verified relocalization)
  /// gives a pose within the noise gates; -> degraded when the model's
  /// pose is usable but not good enough to fuse, or only the frame-to-frame
  /// fallback gives one (neither from lost: the pose is stale then, and the
  /// previous frame has none); -> lost when nothing does.
  TrackingDecision update(const TrackingAttempts& attempts);

  /// `params` with the residual gates of this frame: lowered to shares of
  /// the run's typical consistent share where that is lower (see
  /// TrackingParams::typical_share_fused); with no history yet, the first
  /// model-tracked frame is judged by the fixed gates' lost floor only.
  TrackingParams gates(const TrackingParams& params) const;
  /// The consistent share of a frame the model tracked (ok), for gates().
  void observe(double consistent_ratio, int window);

  TrackingState state() const { return state_; }
  const TrackingCounts& counts() const { return counts_; }
  uint64_t consecutiveLost() const { return lost_run_; }

 private:
  TrackingDecision finish(TrackingDecision d);

  TrackingState state_ = TrackingState::kLost;
  TrackingCounts counts_;
  std::deque<double> consistent_;  ///< newest last
  uint64_t lost_run_ = 0;
};

}  // namespace hxmap::alg
