// The frontend: the per-frame backbone pipeline (paper 3.1). Owns the TSDF,
// the only writer of it. Not thread safe: one thread calls process().
#pragma once

#include <array>
#include <string>
#include <vector>

#include "hxmap/core/frame.hpp"
#include "hxmap/core/parallel.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/quality/quality.hpp"
#include "hxmap/tracking/icp.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "hxmap/tsdf/raycast.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt {

struct FrontendParams {
  alg::PreprocessParams preprocess;
  alg::TsdfParams tsdf;
  alg::RaycastParams raycast;
  alg::TrackingParams tracking;
  alg::QualityParams quality;
  bool quality_enabled = true;  ///< score map regions on keyframes (paper 3.2)
};

/// kQuality runs on keyframes only (0 ms on other frames).
enum Stage { kPreprocess = 0, kTrack, kIntegrate, kRaycast, kQuality, kStageCount };
inline const char* stageName(int s) {
  static const char* names[] = {"preprocess", "track", "integrate", "raycast", "quality"};
  return names[s];
}

struct FrameResult {
  int64_t stamp_ns = 0;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  bool tracked = false;     ///< pose from ICP (or the first frame)
  bool integrated = false;  ///< the frame was fused into the map
  bool keyframe = false;
  uint32_t keyframe_id = 0;   ///< when keyframe: its id (0, 1, ...)
  size_t rois = 0;            ///< when keyframe: ROIs selected after scoring it
  std::string failure;      ///< why the frame was not tracked or not fused
  int inliers = 0;
  double rms_residual_m = 0;
  std::array<double, kStageCount> stage_ms{};
};

/// A corrected pose for a past frame (from pose feedback).
struct PoseCorrection {
  int64_t stamp_ns = 0;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
};

class Frontend {
 public:
  Frontend(const alg::PinholeCamera& camera, const FrontendParams& params,
           ParallelFor parallel = serialFor);

  /// Pose of the first frame (default identity).
  void setInitialPose(const Eigen::Isometry3d& T_world_cam) { T_initial_ = T_world_cam; }

  /// Preprocess, track against the model, integrate, raycast the new model.
  /// A frame that cannot be tracked is reported and not fused; the map is
  /// unchanged and tracking resumes from the last good pose.
  FrameResult process(const RgbdFrame& frame);

  /// Between frames: fuse a correction computed on a snapshot of the map
  /// (the frontend stays the map's only writer).
  alg::PatchStats applyPatch(const alg::TsdfPatch& patch) { return alg::applyPatch(map_, patch); }
  /// Between frames: rewrite the trajectory's pose for that stamp (and the
  /// last keyframe's, when it is that frame). The live pose is re-estimated
  /// against the map by the next frame's tracking. False when no frame has
  /// that stamp.
  bool applyPoseCorrection(const PoseCorrection& correction);

  const alg::TsdfMap& map() const { return map_; }
  const alg::PinholeCamera& camera() const { return camera_; }
  /// Every processed frame's pose (lost frames carry the last good pose).
  const Trajectory& trajectory() const { return trajectory_; }
  size_t lostFrames() const { return lost_frames_; }
  size_t keyframes() const { return keyframes_; }

  /// Quality of the map's regions (paper 3.2), updated on each keyframe.
  const alg::QualityMap& quality() const { return quality_; }
  /// Block scores and ROIs as of the last keyframe.
  const std::vector<alg::BlockScore>& blockScores() const { return scores_; }
  const std::vector<alg::Roi>& rois() const { return rois_; }
  /// The last fused frame and its pose (the last keyframe right after a
  /// keyframe), e.g. to draw the indicators over it.
  const alg::PreprocessedFrame& lastFrame() const { return last_frame_; }
  const Eigen::Isometry3d& lastPose() const { return T_last_; }

 private:
  void renderModel(const alg::PreprocessedFrame& fused);
  void scoreKeyframe(FrameResult& r);

  alg::PinholeCamera camera_;
  FrontendParams params_;
  ParallelFor parallel_;
  alg::TsdfMap map_;
  std::vector<alg::ModelView> model_;  ///< model pyramid rendered at T_last_
  alg::PreprocessedFrame last_frame_;  ///< the last tracked frame (photometric reference)
  bool initialized_ = false;
  Eigen::Isometry3d T_initial_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_last_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d velocity_ = Eigen::Isometry3d::Identity();  ///< T_prev^-1 T_last
  Eigen::Isometry3d T_last_kf_ = Eigen::Isometry3d::Identity();
  int64_t last_kf_ns_ = 0;
  Trajectory trajectory_;
  size_t lost_frames_ = 0, keyframes_ = 0;
  alg::QualityMap quality_;
  std::vector<alg::BlockScore> scores_;
  std::vector<alg::Roi> rois_;
};

}  // namespace hxmap::rt
