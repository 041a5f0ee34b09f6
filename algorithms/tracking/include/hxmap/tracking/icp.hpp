// Frame-to-model point-to-plane ICP (paper eq 1):
//   E(T) = sum_{(p,q,n)} w(p) rho(n^T (T p - q))
// with projective association into the model view, distance gate tau_d,
// normal-angle gate tau_n, Huber loss rho, confidence weights w(p), and
// Gauss-Newton coarse to fine over the frame's pyramid. Failure (too few
// inliers, residuals beyond the sensor's noise, degenerate normal equations,
// implausible motion) is reported, never hidden: the caller keeps the map
// unchanged then. Between success and failure lies a degraded result: a pose
// good enough to follow the camera, not good enough to fuse.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/se3.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/tracking/params.hpp"
#include "hxmap/tsdf/raycast.hpp"

namespace hxmap::alg {

struct IcpResult {
  bool ok = false;
  std::string failure;  ///< why tracking failed, empty when ok
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  int inliers = 0;
  int model_pixels = 0;  ///< valid model pixels at level 0
  double rms_residual_m = 0;
  /// Share of the finest level's associations whose point-to-plane residual
  /// lies within TrackingParams::consistent_sigmas * sigma(z) of the model.
  double consistent_ratio = 0;
  /// Robust spreads of the finest level's residuals (mean |r|, each clipped
  /// at three times its Huber threshold): point-to-plane in meters,
  /// photometric in intensity units (0 without photometric terms).
  double mean_abs_residual_m = 0;
  double photometric_mean_abs = 0;
  /// Why the pose, although usable (ok), is not good enough to fuse; empty
  /// when it is.
  std::string degraded;
  double min_eigen_ratio = 0;
  int iterations = 0;
  Matrix6d information = Matrix6d::Zero();  ///< J^T W J at the solution (level 0)
};

/// The previous frame and its pose, for the photometric term. Point-to-plane
/// residuals leave some motions weakly observed (a camera yawing over a floor,
/// a table and a frontal wall changes them only to second order); intensity
/// edges observe them directly, as in ElasticFusion's joint cost.
struct PhotometricReference {
  const PreprocessedFrame* frame = nullptr;
  /// The pose of the reference's color image.
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  /// Where the current frame's color camera was, relative to the pose being
  /// estimated (its depth camera's): T_color = T * T_depth_color. Identity
  /// when color and depth are taken together; for a sensor that does not
  /// synchronize them, the camera's motion over the time between the two.
  /// DESIGN: on the TUM fr1 recordings color and depth are up to 17 ms
  /// apart and the offset flips sign from one frame to the next; with the
  /// motion between them ignored, the photometric term pulled the pose
  /// 5-10 mm off the depth's, and the share of depth residuals within the
  /// noise gate fell from 97-100 % to 20-45 % on those frames.
  Eigen::Isometry3d T_depth_color = Eigen::Isometry3d::Identity();
  /// When > 0, T_depth_color is instead taken from the motion being
  /// estimated, in every Gauss-Newton step: the camera is assumed to move
  /// uniformly from T_world_previous (the previous depth image's pose)
  /// to the current estimate T, and the color image lies
  /// color_offset_ratio (offset / frame interval, signed) of that motion
  /// beyond T. color_offset_ratio 0: T_depth_color as given.
  Eigen::Isometry3d T_world_previous = Eigen::Isometry3d::Identity();
  double color_offset_ratio = 0.0;
};

/// `model[l]` is the model rendered at the reference pose for pyramid level l
/// (model.size() <= frame.levels.size()). T_init is the initial guess. With a
/// reference (and photometric_scale_m > 0) photometric residuals join the
/// point-to-plane ones in each Gauss-Newton step. Row bands are summed in a
/// fixed order, so the result is the same for any `parallel`.
IcpResult trackPointToPlane(const PreprocessedFrame& frame, const std::vector<ModelView>& model,
                            const Eigen::Isometry3d& T_init, const TrackingParams& params,
                            const PhotometricReference& reference = {}, const ParallelFor& parallel = serialFor);

/// A frame as the model to track the next frame against (frame-to-frame
/// odometry): its vertex and normal maps at `T_world_cam`, level by level
/// from its finest preprocessed level (finer entries repeat that one).
std::vector<ModelView> frameAsModel(const PreprocessedFrame& frame, const Eigen::Isometry3d& T_world_cam);

/// The pyramid level the model is raycast at for an image `width` pixels
/// wide (params.model_level, or the automatic choice when it is negative).
int modelLevel(const TrackingParams& params, int width);

/// Keyframe test: motion or time since the last keyframe above thresholds;
/// `last_kf_depth_m`, the last keyframe's median depth (0: unknown), scales
/// the translation threshold (TrackingParams::keyframe_baseline_ratio), and
/// so does the map's `voxel_size_m` (0: unknown;
/// TrackingParams::keyframe_translation_voxels).
bool isNewKeyframe(const Eigen::Isometry3d& T_last_kf, const Eigen::Isometry3d& T_now, int64_t last_kf_ns,
                   int64_t now_ns, const TrackingParams& params, double last_kf_depth_m = 0.0,
                   double voxel_size_m = 0.0);

/// Median of the valid (> 0, finite) depths of `depth_m` (CV_32F), 0 when none.
float medianDepth(const cv::Mat& depth_m);

}  // namespace hxmap::alg
