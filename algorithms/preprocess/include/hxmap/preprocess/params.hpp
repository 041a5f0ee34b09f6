#pragma once

namespace hxmap::alg {

/// Depth preprocessing and per-pixel confidence. Units in field names.
struct PreprocessParams {
  double min_depth_m = 0.1;        ///< closer depth is invalid
  double max_depth_m = 5.0;        ///< farther depth is invalid
  int bilateral_radius_px = 2;     ///< 0 disables the edge-preserving denoise
  double bilateral_sigma_px = 1.5; ///< spatial sigma of the denoise
  double bilateral_sigma_depth_factor = 2.5;  ///< range sigma = factor * sensor sigma(z)
  int pyramid_levels = 3;          ///< levels for tracking (1..5)
  /// Sensor noise model sigma(z) = a + b (z - 0.4)^2 (Kinect v1 values).
  double noise_sigma_a_m = 0.0012;
  double noise_sigma_b_per_m = 0.0019;
  double edge_jump_sigmas = 6.0;        ///< depth discontinuity: jump > this many sigma(z)
  double edge_confidence_distance_px = 4.0;  ///< confidence ramps to 1 this far from an edge
  double max_incidence_deg = 80.0;      ///< pixels viewed more obliquely get 0 confidence
};

}  // namespace hxmap::alg
