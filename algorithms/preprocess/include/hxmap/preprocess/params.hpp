#pragma once

namespace hxmap::alg {

/// Depth preprocessing and per-pixel confidence. Units in field names.
struct PreprocessParams {
  double min_depth_m = 0.1;        ///< closer depth is invalid
  double max_depth_m = 5.0;        ///< farther depth is invalid
  /// Edge-preserving denoise at finest_level (0 disables it). Radius 1 (9
  /// taps instead of 25) measured the same ATE and mesh at 640x480 (TUM
  /// slice / synthetic orbit / sweep / Replica slice 0.53 / 0.13 / 0.12 /
  /// 0.02 cm; mesh F1 at 1 cm 92.4 / 95.8% vs 92.5 / 95.7%) at a quarter less
  /// preprocessing (6.4 -> 4.7 ms on one core), but on the 320x240 drift
  /// test of pose feedback the window then removed 18% of the drift instead
  /// of 26% (tests/integration/test_pose_feedback.cpp): kept at 2.
  int bilateral_radius_px = 2;
  double bilateral_sigma_px = 1.5; ///< spatial sigma of the denoise
  double bilateral_sigma_depth_factor = 2.5;  ///< range sigma = factor * sensor sigma(z)
  /// Pyramid level at which filtering, normals and confidence start; finer
  /// levels keep only their depth. 1 (half resolution) serves tracking and
  /// fusion at a quarter of the cost of full resolution (see DESIGN in
  /// preprocess.cpp for the measurements).
  int finest_level = 1;
  int pyramid_levels = 3;          ///< processed levels from finest_level on (1..5)
  /// Sensor noise model sigma(z) = a + b (z - 0.4)^2 (Kinect v1 values).
  double noise_sigma_a_m = 0.0012;
  double noise_sigma_b_per_m = 0.0019;
  double edge_jump_sigmas = 6.0;        ///< depth discontinuity: jump > this many sigma(z)
  /// Confidence ramps to 1 this far from an edge, in pixels of the level
  /// (2 at half resolution = 4 full-resolution pixels; measured 4: mesh F1@1cm
  /// orbit/sweep 91.9/93.9%, 2: 92.5/95.7%).
  double edge_confidence_distance_px = 2.0;
  double max_incidence_deg = 80.0;      ///< pixels viewed more obliquely get 0 confidence
};

}  // namespace hxmap::alg
