// Parameters of the keyframe database and relocalization. Units in names.
#pragma once

namespace hxmap::alg {

struct RelocalizationParams {
  bool enabled = true;
  int features = 800;  ///< ORB features per image (at most)
  /// FAST corner threshold (intensity levels of 255). ORB's default 20
  /// finds few corners on low-contrast surfaces: on the synthetic room 250
  /// features per image and 19 PnP inliers a third of a second from a
  /// keyframe, at 10 520 features and 103 inliers.
  int fast_threshold = 10;
  int max_keyframes = 400;       ///< kept (about 35 KB each at 800 features)
  double ratio_test = 0.8;       ///< nearest / second-nearest descriptor distance
  int min_matches = 20;      ///< matched features before PnP is tried
  int min_pnp_inliers = 15;  ///< and its consensus
  double pnp_reprojection_px = 3.0;  ///< RANSAC inlier threshold at full resolution
  int pnp_iterations = 300;
  /// Keyframes matched per attempt (all kept ones when <= 0): half of them
  /// the nearest to the last known pose, half taken in turn from the rest,
  /// so that consecutive attempts cover the whole database at a bounded
  /// cost per frame.
  int candidates = 12;
  /// Of those, the ones with the most descriptor matches get PnP + RANSAC.
  int pnp_candidates = 3;
  /// The ICP that verifies a candidate may move it at most this far from
  /// the PnP pose (two independent estimates must agree).
  double max_icp_correction_m = 0.05;
  double max_icp_correction_deg = 3.0;
};

}  // namespace hxmap::alg
