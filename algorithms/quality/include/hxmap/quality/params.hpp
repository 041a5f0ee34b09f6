#pragma once

#include <string>

namespace hxmap::alg {

/// Quality-guided region selection (paper 3.2, eq 2-7). A region is one
/// voxel block. Depth quantities inside an indicator are in units of the
/// truncation distance mu and clamped to 1, so every term of eq 2-5 lies in
/// [0, 1] and the weights within an indicator compare like with like.
struct QualityParams {
  /// Pixel stride at the model level (half resolution): 2 reads every 4th
  /// pixel of a 640x480 keyframe (19200 samples).
  int pixel_stride = 2;
  /// A keyframe updates a block's indicators only from this many samples on.
  int min_samples = 4;
  /// Weight of the newest keyframe in the running normal novelty, boundary
  /// share and mismatch of a block (exponential average over keyframes).
  double smoothing = 0.5;

  double alpha_coverage = 0.5;     ///< CGN (eq 2): how newly covered the block is (few usable views yet)
  double alpha_normal = 0.5;       ///< CGN: normal novelty 1 - cos
  double w_explicit = 0.5;         ///< UF (eq 3): sigma_TSDF
  double w_implicit = 0.5;         ///< UF: sigma_Neural, where a neural field exists
  double beta_depth_var = 0.5;     ///< OBG (eq 4): depth mismatch spread across viewpoints
  double beta_boundary = 0.5;      ///< OBG: share of samples on occlusion boundaries
  double gamma_photometric = 0.5;  ///< RM (eq 5): |I_input - I_render|, intensity in [0, 1]
  double gamma_depth = 0.5;        ///< RM: |z_input - z_render|
  /// A block counts as covered (C_new = 0) once this many keyframes saw the
  /// map's surface in it at an incidence below max_view_incidence_deg (each
  /// with min_samples such pixels, the model's normal against the ray; a
  /// surface point counts for the blocks within half a voxel of it along its
  /// normal, so a surface on a block face counts for both sides);
  /// before, C_new = 1 - usable views / consolidated_views.
  int consolidated_views = 3;
  double max_view_incidence_deg = 75.0;
  /// A keyframe flags a block as on an occlusion boundary (B_occ = 1) when
  /// this share of its samples lies next to a depth jump (less: in proportion).
  double boundary_full_share = 0.1;
  /// A sample is on an occlusion boundary when a pixel within
  /// boundary_radius_px (model level) is farther by more than this * z (the
  /// near side of the jump: the occluder's edge, not its shadow).
  double boundary_jump_ratio = 0.05;
  int boundary_radius_px = 2;

  double lambda_cgn = 0.25;  ///< priority S (eq 7)
  double lambda_uf = 0.25;
  double lambda_obg = 0.25;
  double lambda_rm = 0.25;
  /// How S combines the weighted normalized indicators: "max" (default),
  /// max_k lambda_k I_k / max_k lambda_k, or "sum", eq 7's sum_k lambda_k
  /// I_k. DESIGN: the four indicators measure different failure modes
  /// (coverage, noise, occlusion geometry, rendering mismatch), and a
  /// region is bad when any one of them fires. Under the sum, moderate
  /// values of several (a far clean wall: some noise, a few good views)
  /// outranked one strong one (a board's edge: occlusion only). On the
  /// quality room (bench_quality, when this was measured), precision /
  /// recall at a 15 % budget went from 83.5 / 66.4 % to 90.1 / 71.7 % on the
  /// inspect path and from 80.9 / 60.1 % to 93.6 / 69.6 % on the sweep path;
  /// at 18 %, on the sweep path, from 77.1 / 68.2 % to 82.4 / 73.0 %
  /// (inspect unchanged, 80.0 / 76.3 %).
  std::string priority_rule = "max";

  /// Budget: the top share of scored blocks by S, at most max_blocks.
  double top_fraction = 0.1;
  int max_blocks = 512;
  double min_priority = 0.0;  ///< blocks below are never chosen
  /// ROIs: connected chosen blocks, cut into cubes of at most this many
  /// blocks per side, grown by a margin, with the keyframes that saw them.
  int roi_max_extent_blocks = 4;
  int roi_margin_voxels = 2;
  int roi_max_keyframes = 8;
  /// Which keyframes a block keeps (BlockQuality::kMaxKeyframes of them)
  /// and an ROI trains on: true, the ones that saw it from the most
  /// different directions (a new keyframe always enters; out goes the older
  /// of the two closest in direction); false, the most recent.
  bool spread_keyframes = true;
};

}  // namespace hxmap::alg
