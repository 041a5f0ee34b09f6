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
  /// Loop factors (a PnP pose confirmed by ICP against the map): these
  /// sigmas in the direction ICP constrains best, larger ones where it
  /// constrains less, their information down to loop_min_information_ratio
  /// of the best direction's.
  double loop_sigma_m = 0.01;
  double loop_sigma_deg = 0.5;
  /// Measured on the synthetic loop (0.1 deg, 2 mm drift per frame) and
  /// the quality room: 0 gives ATE 1.44 cm and no closure on the room
  /// (0.12 cm, as without loop closure); 0.1 gives 1.41 cm but a 2.3 cm
  /// closure on the room that tracking did not need (0.86 cm); 1
  /// (isotropic) 1.12 cm and a 3.1 cm one (1.13 cm).
  double loop_min_information_ratio = 0.0;
  /// A closure is refused when, with it, any factor's whitened error
  /// exceeds the square root of this chi-square value (6 degrees of
  /// freedom; 22.46 is the 99.9 % quantile).
  double gate_chi2 = 22.46;
  /// A closure is plausible only when its correction is within the drift
  /// odometry can accumulate over the path since the old keyframe:
  /// max_drift_m + max_drift_per_m * path (meters), and max_drift_deg +
  /// max_drift_deg_per_m * path (degrees). A place that merely looks the
  /// same (a repeated texture, another corner of the same kind) is usually
  /// far beyond it.
  double max_drift_m = 0.05;
  double max_drift_per_m = 0.1;
  double max_drift_deg = 2.0;
  double max_drift_deg_per_m = 5.0;
  /// Tracked motion between keyframes is replaced by the keyframes'
  /// alignment when the two differ by more than this many odometry sigmas.
  /// Measured: 3 left the drift of the synthetic loop (0.1 deg and 2 mm
  /// injected per frame) hidden in tracking's snaps (ATE 9.8 -> 9.6 cm
  /// where 1 gives 1.4 cm); 1 changes nothing on the quality room and the
  /// orbit and gives 1.20 -> 1.13 cm on TUM fr1/xyz.
  double jump_sigmas = 1.0;
  /// A verified closure that moves the keyframe less than this (both
  /// bounds) only adds its factor: the map is already consistent there.
  double min_correction_m = 0.02;
  double min_correction_deg = 1.0;
  /// Keyframe observations kept to rebuild the map after a closure (the
  /// images fusion read, about 2.4 MB each at 640x480: 290 MB at most);
  /// past it, every other one of the older half is let go.
  int max_stored_keyframes = 120;
};

}  // namespace hxmap::alg
