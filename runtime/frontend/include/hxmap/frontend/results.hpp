// What the frontend reports: per frame (FrameResult, with its stages'
// times) and summed over a run (counters), for runners, the summary and
// observers such as the DDS publisher.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

#include <Eigen/Geometry>

#include "hxmap/tracking/state.hpp"

namespace hxmap::rt {

/// kKeyframe runs on keyframes only (0 ms on other frames): quality
/// scoring, refinement jobs and the keyframe database's features.
enum Stage { kPreprocess = 0, kTrack, kIntegrate, kRaycast, kKeyframe, kStageCount };
inline const char* stageName(int s) {
  static const char* names[] = {"preprocess", "track", "integrate", "raycast", "keyframe"};
  return names[s];
}

struct FrameResult {
  int64_t stamp_ns = 0;  ///< the time the pose refers to: the depth image's capture
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  /// The corrections loop closure has applied so far, composed: the pose in
  /// an odometry frame that never jumps at a closure is T_world_odom⁻¹ ·
  /// T_world_cam (REP 105's map -> odom is this transform).
  Eigen::Isometry3d T_world_odom = Eigen::Isometry3d::Identity();
  bool tracked = false;  ///< the frame has a pose (tracked or degraded; the first frame)
  alg::TrackingState state = alg::TrackingState::kLost;
  alg::PoseSource pose_source = alg::PoseSource::kNone;
  bool integrated = false;  ///< the frame was fused into the map
  bool keyframe = false;
  uint32_t keyframe_id = 0;  ///< when keyframe: its id (0, 1, ...)
  size_t rois = 0;           ///< when keyframe: ROIs selected after scoring it
  std::string failure;       ///< why the frame was not tracked or not fused
  int inliers = 0;
  double rms_residual_m = 0;
  double consistent_ratio = 0;  ///< share of associations within the noise gate
  std::array<double, kStageCount> stage_ms{};
};

/// What a runner knows about a frame beyond its result, for observers such
/// as the DDS publisher (zeros where the runner has no such figure).
struct RunCounters {
  uint64_t frames_dropped = 0, deadline_misses = 0, refine_jobs_done = 0, refine_jobs_shed = 0;
  double latency_ms = 0;  ///< this frame: arrival to pose
};

/// The memory budget (tsdf max_resident_mib), summed over a run.
struct MemoryCounters {
  uint64_t evicted = 0;          ///< blocks moved out of memory
  uint64_t prefetched = 0;       ///< blocks brought back ahead of the camera
  uint64_t taken_back = 0;       ///< all blocks brought back (prefetch and fusion)
  uint64_t lost = 0;             ///< blocks the store failed to keep or give back
  uint64_t prefetch_capped = 0;  ///< blocks in view left out by the per-frame cap (not back yet)
  uint64_t prefetch_not_ready = 0;  ///< ... left for a later frame: not read ahead yet (wait_for_blocks false)
  size_t resident_bytes_max = 0;
  uint64_t frames_over_budget = 0;  ///< frames that ended above the budget (after a loop closure's new map)
  double evict_ms_total = 0, evict_ms_max = 0;
  double prefetch_ms_total = 0, prefetch_ms_max = 0;
};

/// How tracking found its poses, summed over a run.
struct TrackingCounters {
  uint64_t velocity_retries = 0;         ///< frames tracked a second time from the constant-velocity guess
  uint64_t velocity_wins = 0;            ///< ... where that guess gave the better result
  double photometric_scale_m = 0;        ///< the photometric weight the last frame was tracked with
  uint64_t relocalization_attempts = 0;  ///< lost frames matched against the keyframe database
  uint64_t relocalization_rejected = 0;  ///< PnP candidates the ICP check refused
  double relocalization_ms = 0;          ///< total over the attempts
  double relocalization_features_ms = 0, relocalization_query_ms = 0;  ///< of which ORB, and matching + PnP
  double keyframe_features_ms = 0;                                     ///< total ORB extraction for the database
  uint64_t interpolated_poses = 0;  ///< lost frames given poses between the ones either side, once found again
  size_t database_keyframes = 0, database_bytes = 0;
};

}  // namespace hxmap::rt
