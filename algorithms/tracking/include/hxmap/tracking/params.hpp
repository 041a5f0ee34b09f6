#pragma once

namespace hxmap::alg {

/// Frame-to-model point-to-plane ICP (paper eq 1). Units in field names.
struct TrackingParams {
  /// Gauss-Newton iterations at most per level; some frames converge
  /// sooner (convergence_* below). The coarse levels bring the pose within
  /// the finest level's basin: three iterations there measured as accurate
  /// as four at a quarter less tracking time (ATE TUM slice / synthetic
  /// orbit / sweep / Replica slice 0.53 / 0.13 / 0.12 / 0.02 cm either way).
  /// Two (3 and 6 at the coarser levels) tracked as well, but pose feedback
  /// on a drift-free synthetic sequence then measured worse than none
  /// (ATE 1.52 -> 1.88 mm, tests/integration/test_pose_feedback.cpp).
  int iterations_finest = 3;  ///< the frame's finest preprocessed level
  int iterations_middle = 4;
  int iterations_coarsest = 8;  ///< the third level and coarser
  /// Pyramid level at which the model is raycast for tracking; finer levels
  /// associate into it (projectively, nearest model pixel; the residual is
  /// to the model's plane there). -1 = auto: the level at which the image
  /// is 160 to 319 pixels wide, at least 1 (see modelLevel). At 640x480 the
  /// model at level 2 (160x120) measured the same ATE as level 1 (TUM slice
  /// / synthetic orbit / sweep / Replica slice 0.53 / 0.13 / 0.12 / 0.02 cm)
  /// at a quarter of the raycast (11.6 -> 3.2 ms per frame on one core);
  /// level 1 had measured the same as level 0 earlier.
  int model_level = -1;
  /// Pixel stride of point-to-plane terms at the finest tracking level
  /// (half resolution by default). 2 saves a third of the tracking time but
  /// measured less accurate on synthetic data (ATE TUM / orbit / sweep /
  /// Replica 0.52 / 0.18 / 0.14 / 0.04 cm vs 0.53 / 0.13 / 0.12 / 0.02).
  int icp_stride_finest = 1;
  double max_correspondence_distance_m = 0.1;  ///< tau_d
  double max_normal_angle_deg = 30.0;          ///< tau_n
  double huber_delta_m = 0.01;                 ///< robust loss rho
  /// Photometric term (the previous frame warped into the current one), in
  /// the same Gauss-Newton: residuals in intensity units [0, 1] are scaled
  /// by this many meters per unit, so that they weigh against point-to-plane
  /// residuals. 0 disables it (geometry only). DESIGN: the ratio of the two
  /// noises, about 2 mm of depth (sigma(z) near 1 m) to 0.01 of intensity
  /// (2-3 levels of an 8-bit camera). Measured, ATE whole TUM fr1/xyz /
  /// its first 40 frames / synthetic orbit / synthetic fast: 0 -> 1.41 (color
  /// stamps) / - / 19.5 (earlier build) cm; 0.1 -> 1.16 / - / 0.15 / -; 0.2
  /// -> 1.28 / 0.52 / 0.12 / 0.12; 0.5 (the earlier default) -> 1.57 (color
  /// stamps) / 0.66 / 0.12 / 0.12. Without the photometric term rotation
  /// drifts most (RPE 1.54 deg/s on fr1/xyz against 1.06 at 0.2).
  double photometric_scale_m = 0.2;
  /// The two noises measured instead of assumed: the weight becomes the
  /// ratio of the point-to-plane to the photometric residuals' robust spread
  /// (mean |r|, clipped) over the last photometric_scale_window fused
  /// frames (median), within 1/4 and 4 times photometric_scale_m, which
  /// stays the weight of the first frames. A camera whose color is blurred,
  /// compressed or taken out of step with its depth gets less photometric
  /// weight; a sharp synchronized one more. Measured (ATE, refinement
  /// off, fixed 0.2 -> from residuals): whole fr1/xyz 1.28 -> 1.20 cm (its
  /// weight settles near 0.14; rotation RPE 1.04 -> 1.19 deg/s), its first
  /// 40 frames 0.52 -> 0.52, synthetic orbit 0.12 -> 0.16, sweep 0.13 ->
  /// 0.12, fast 0.12 -> 0.14, fast with the hand-held color camera 0.27 ->
  /// 0.28, Replica slice 0.01 -> 0.01 (synthetic weights 0.05-0.13: the
  /// renderer's texture aliasing between views counts as color noise).
  bool photometric_scale_from_residuals = true;
  int photometric_scale_window = 30;
  double photometric_huber = 0.05;         ///< robust loss threshold, intensity units
  /// The photometric term's reference image: the last keyframe (true) or
  /// the previous frame (false). Measured (ATE fr1/xyz / first 40 frames /
  /// synthetic orbit / fast): keyframe 1.31 / 0.56 / 0.07 / 0.09 cm,
  /// previous frame 1.28 / 0.52 / 0.12 / 0.12.
  bool photometric_keyframe_reference = false;
  double photometric_min_gradient = 0.01;  ///< pixels with flatter intensity are not used
  /// Reference pixels whose own gradient is below this fraction of
  /// photometric_min_gradient are not warped (nearly all would fail the
  /// test in the current image). Measured (tracking ms per frame on one
  /// core, ATE TUM slice / orbit / sweep / Replica slice): 0 -> 9.2 ms,
  /// 0.53 / 0.13 / 0.13 / 0.02 cm; 0.3 -> 8.7 ms, the same ATE; 0.5 ->
  /// 8.4 ms, 0.54 / 0.12 / 0.13 / 0.02; 0.7 -> 7.9 ms, 0.54 cm on TUM.
  double photometric_reference_gradient_ratio = 0.3;
  /// Pixel stride of photometric terms at the finest level, which uses
  /// full-resolution intensity when the frames have it (cost).
  int photometric_stride_finest = 2;
  /// A level stops when the step is below both. Measured (ATE orbit/sweep/
  /// TUM): 1e-5 -> 0.14/0.13/0.53 cm at 18 iterations per frame; 1e-4 ->
  /// 0.15/0.13/0.53 cm at about half the iterations; 2e-4 -> 0.18 cm orbit.
  double convergence_translation_m = 1e-4;
  double convergence_rotation_rad = 1e-4;
  /// Failure detection.
  double min_inlier_ratio = 0.15;  ///< of the valid model pixels
  int min_inliers = 800;
  /// Residual gates from the sensor's noise model, not a fixed distance:
  /// an association is consistent when its point-to-plane residual lies
  /// within consistent_sigmas * sigma(z) at the point's depth z. A frame is
  /// fused when at least min_consistent_ratio of its associations are
  /// consistent, still followed (degraded: the pose moves, the map does not)
  /// down to min_consistent_ratio_lost, and failed below that.
  double consistent_sigmas = 3.0;
  double min_consistent_ratio = 0.5;
  double min_consistent_ratio_lost = 0.2;
  /// A camera noisier than the noise model says (or a young map) agrees
  /// less with the model even when tracking is right: both gates are
  /// lowered to these shares of the run's typical consistent share (the
  /// median over the last consistent_window frames the model tracked)
  /// when that is lower. They never tighten.
  double typical_share_fused = 0.6;
  double typical_share_lost = 0.3;
  int consistent_window = 60;
  /// After a loss of more than this many frames, a model result far from
  /// the last pose (beyond RelocalizationParams::max_icp_correction_*) is
  /// taken only when relocalization confirms it; after a shorter loss
  /// (a few corrupt frames) the camera is still near the last pose.
  int short_loss_frames = 5;
  /// A frame that associates less than this share of the view is followed,
  /// not fused (the model it met is too small a part of what it sees).
  double min_inlier_ratio_fused = 0.3;
  /// The sensor's noise model sigma(z) = a + b (z - 0.4)^2; the frontend
  /// sets it from the preprocessing's (PreprocessParams), one model for both.
  double noise_sigma_a_m = 0.0012;
  double noise_sigma_b_per_m = 0.0019;
  double min_hessian_eigenvalue_ratio = 1e-5;  ///< smallest/largest eigenvalue of the normal equations
  double max_motion_translation_m = 0.3;       ///< per frame, larger is a failure
  double max_motion_rotation_deg = 30.0;
  /// A frame the model does not track within the gates from the last pose
  /// is tracked again from the constant-velocity prediction, and the better
  /// of the two kept (fast motion leaves the last pose outside the basin).
  /// DESIGN: only as a retry: seeding every frame with the last motion made
  /// weakly observed motions (a camera yawing over a floor, a table and a
  /// frontal wall) grow geometrically on the synthetic room (47 cm ATE, an
  /// earlier build). On fr1/xyz and the synthetic fast path the retry ran on
  /// 1 frame and changed no figure.
  bool constant_velocity = true;
  /// Color taken at another instant than depth (unsynchronized sensors):
  /// the color camera's pose is placed along the motion being estimated
  /// (from the previous frame's pose to the current estimate, in every
  /// Gauss-Newton step) rather than along the previous frame's velocity.
  /// Measured (ATE, synthetic fast trajectory, color 12 ms after depth):
  /// 0.29 -> 0.17 cm; with the whole hand-held color camera of `hxmap synth
  /// --handheld-camera` 0.37 -> 0.27; whole fr1/xyz 1.28 either way.
  bool color_offset_from_motion = true;
  /// Keyframes.
  double keyframe_translation_m = 0.1;
  /// Also a keyframe once the translation exceeds this many voxels of the
  /// map (0: off): 10 cm at 2 cm voxels as above, 5 cm at 1 cm.
  ///
  /// DESIGN: every other length of the map and of refinement is in voxels
  /// (truncation, sample bands, Huber scales), so a scene half the size
  /// mapped at half the voxel size gives the same images at half the depth
  /// and the same map, scaled; a keyframe spacing fixed in meters was the one
  /// length that broke this, and keyframes are the views refinement trains
  /// on. On the half-size quality room at 1 cm voxels the refined ROIs' F1
  /// gain went from +8.1 (10 cm) to +13.4 and +14.7 points in two runs (5
  /// cm, with this default); at 2 cm voxels, the TUM slice and Replica
  /// nothing changes.
  double keyframe_translation_voxels = 5.0;
  /// Also a keyframe once the translation exceeds this share of the last
  /// keyframe's median depth (0, the default: off). What keyframes are for
  /// (views of a surface from different directions, for quality scoring,
  /// refinement and pose feedback) is parallax, which scales with the
  /// distance to the scene: at 0.04 a wall 2.5 m away gets a keyframe
  /// every 10 cm as with the fixed threshold, a table top 1.2 m away every
  /// 5 cm. On the quality room at half size and 1 cm voxels it raised the
  /// refined ROIs' F1 gain from +8.7 to +11.4 points (before
  /// keyframe_translation_voxels, and before the mesh metrics left out
  /// ground truth seen only at grazing angles). It is off by default
  /// because on the TUM slice (about 1 m away) the 10 instead of 4
  /// keyframes made more refinement jobs and pose-feedback corrections, and
  /// ATE went from 0.53-0.54 to 0.54-0.57 cm over six runs each (median
  /// 0.54 -> 0.55; pose feedback runs beside the frontend, so runs differ;
  /// 0.53 for both with feedback off).
  double keyframe_baseline_ratio = 0.0;
  double keyframe_rotation_deg = 10.0;
  double keyframe_interval_s = 1.0;
};

}  // namespace hxmap::alg
