// Parameters of the sliding-window pose feedback (paper 3.4, eq 12-13).
#pragma once

namespace hxmap::alg {

struct FeedbackParams {
  /// Off by default: it does not lower ATE on real recordings. On the whole
  /// TUM fr1/xyz (792 frames) 1.19 cm with it against 1.20 cm without
  /// (refinement and loop closure off), 1.15 against 1.10 cm with both on:
  /// with a few thousand pixels per keyframe the window cannot beat
  /// tracking's whole frames where tracking does not drift.
  bool enabled = false;
  int window = 8;                 ///< N keyframes whose poses are the variables
  int image_level = 1;            ///< pyramid level of the keyframe images used (0 = full size)
  /// Omega_j: a uniform base set, plus per iteration the pixels with the
  /// largest residuals of the previous iteration and a fresh uniform set
  /// that lets new large residuals be found.
  int base_pixels = 1536;
  int top_pixels = 256;
  int explore_pixels = 256;
  int iterations = 4;             ///< Levenberg-Marquardt iterations per solve (accepted or not)
  /// Rays are cast into the maps again after this many accepted steps; in
  /// between, steps are judged and linearized on the tangent planes of the
  /// last cast (1: cast at every step).
  int relinearize_every = 2;
  /// A keyframe already solved starts the next solve from its last planes
  /// (its base pixels are not cast until the first recast).
  bool reuse_planes = true;
  /// Per-channel weights (eq 13): explicit (TSDF raycast) and implicit
  /// (neural fields inside refined ROIs) photometric and depth.
  double lambda_photo_explicit = 0.5;
  double lambda_depth_explicit = 1.0;
  double lambda_photo_implicit = 0.5;
  double lambda_depth_implicit = 1.0;
  /// Residual scales (normalize the channels) and robust weights: Huber at
  /// one scale; residuals beyond the gate are outliers (dropped).
  double depth_sigma_m = 0.01;
  double photo_sigma = 0.05;      ///< intensity 0..1
  double depth_gate_m = 0.05;
  /// Depth residuals as point-to-plane distances (the along-ray residual
  /// D - D^ times the incidence cosine), as tracking's ICP measures them.
  /// DESIGN: along the ray, a small error of the fused surface on a
  /// slanted plane (a desk seen at 60-75 degrees) grows by 1 / cos (2-4x)
  /// and the window pulled the keyframes away from where tracking, which
  /// fused that map, had put them: on the TUM slice the keyframe ATE went
  /// 0.15 -> 0.33 cm with along-ray residuals, 0.15 -> 0.17 cm with these;
  /// the drift removed on the biased synthetic orbit is about the same.
  bool depth_point_to_plane = true;
  double photo_gate = 0.3;
  /// The keyframe's intensity is blurred by this Gaussian sigma (pixels)
  /// before comparison: the map's colors are averages over a voxel, and a
  /// sharper image than the map biases the photometric term near edges.
  double photo_blur_px = 1.0;
  /// Pixels next to a depth jump larger than this times their depth (or a
  /// hole) are left out of Omega.
  double edge_depth_ratio = 0.02;
  double min_gradient = 0.02;     ///< photometric pixels need |grad I| (per pixel) above this
  double max_incidence_deg = 75;  ///< rays more grazing than this to the surface are skipped
  /// Relative-pose factors between consecutive keyframes carry the ICP
  /// information times this (the ICP Hessian ignores correlated errors and
  /// is overconfident by orders of magnitude); 0 = no such factors.
  double odometry_information_scale = 1e-3;
  double lm_initial_damping = 1e-4;
  /// Feedback: a keyframe's estimate goes to the frontend only when it
  /// differs from the pose the frontend has by more than the solve's own
  /// noise: delta^T Lambda delta above this (Lambda its marginal
  /// information; chi-square, 6 degrees of freedom: 16.8 = 99%). The window
  /// has a few thousand pixels against tracking's whole frame: without
  /// drift it cannot beat tracking, only add its noise.
  double min_correction_chi2 = 16.8;
  /// Feedback: and only when the solution lowers both the keyframe's depth
  /// and its photometric cost (on its base pixels; a keyframe without
  /// texture has no photometric cost to raise). DESIGN: the two sensors
  /// err independently, and where one has a systematic error the solve
  /// trades the other against it with high confidence: on the TUM slice,
  /// corrections with chi-square 20-400 moved keyframes away from the
  /// ground truth (ATE +5.1% with feedback); with this test +1.1%, and the
  /// biased-odometry orbit keeps most of its correction (-45% vs -50%).
  bool require_channel_agreement = true;
  /// Feedback: and only when a dense check agrees (PoseWindow::verify):
  /// every verify_stride-th usable pixel of the keyframe's image in both
  /// directions (0 = no check). DESIGN: the window's sample (a few thousand
  /// pixels) and its Hessian are overconfident; on the whole TUM fr1/xyz the
  /// keyframes it corrected were 4 % further from the ground truth than
  /// tracking had them (1.20 -> 1.25 cm over those keyframes); with this
  /// check, on a quarter of the pixels, 5 % closer (1.16 -> 1.10 cm).
  int verify_stride = 2;
  /// Feedback: keyframes whose pose moved more than this are re-integrated.
  double reintegrate_translation_m = 0.003;
  double reintegrate_rotation_deg = 0.2;
  unsigned seed = 1;              ///< uniform pixel sets (deterministic)
};

}  // namespace hxmap::alg
