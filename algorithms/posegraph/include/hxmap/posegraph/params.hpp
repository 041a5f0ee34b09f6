// Loop closure: which keyframes are compared, how the closure is verified
// and weighed in the pose graph. Units in names.
#pragma once

namespace hxmap::alg {

struct LoopClosureParams {
  bool enabled = true;
  /// A keyframe is compared with keyframes at least this many keyframes
  /// older (the recent ones are tracking's business).
  int min_keyframe_gap = 20;
  /// Odometry factors between consecutive keyframes: standard deviation per
  /// axis (tracking's own information is overconfident by orders of
  /// magnitude: a window of them failed its chi-square on real data).
  double odometry_sigma_m = 0.01;
  double odometry_sigma_deg = 0.5;
  /// Loop factors (a PnP pose confirmed by ICP against the map).
  double loop_sigma_m = 0.01;
  double loop_sigma_deg = 0.5;
  /// A closure is refused when, with it, any factor's whitened error
  /// exceeds the square root of this chi-square value (6 degrees of
  /// freedom; 22.46 is the 99.9 % quantile).
  double gate_chi2 = 22.46;
  /// A verified closure that moves the keyframe less than this (both
  /// bounds) only adds its factor: the map is already consistent there.
  double min_correction_m = 0.02;
  double min_correction_deg = 1.0;
  /// Keyframe observations kept to rebuild the map after a closure (the
  /// images fusion read, about 2.4 MB each at 640x480); past it, every
  /// other one of the older half is let go.
  int max_stored_keyframes = 200;
};

}  // namespace hxmap::alg
