#pragma once

#include <cstdint>

namespace hxmap::alg {

/// Implicit local refinement of one ROI (paper 3.3, eq 8-11). Lengths are in
/// voxels of the map unless the name says otherwise.
struct ImplicitParams {
  // Field (eq 8-9). F_geo has two scales: one node per voxel (the TSDF's
  // signed distance and normal) and fine_per_voxel nodes per voxel (a signed
  // distance detail, zero at start). F_tex has one node per voxel (color).
  int fine_per_voxel = 2;
  // DESIGN: the grids carry the geometry (the fine grid resolves below the
  // voxel); the decoder adds corrections and color. At 8 / 16 it costs 496
  // multiply-adds a sample against 1248 at 16 / 32, and a job 0.6 of the
  // time; the quality room's F1 gain inside the ROIs stayed within the
  // spread of the seeds (2 cm: +20.3 against +20.1 / +21.1; half size at
  // 1 cm: +10.6 against +11.3). Halving samples_per_ray as well cost 2-5
  // points.
  int fuse_width = 8;            ///< Phi_fuse output features
  int hidden_width = 16;         ///< decoder hidden layer
  int encoding_frequencies = 2;  ///< sin/cos octaves of the local position
  uint64_t seed = 1;             ///< initial weights and ray sampling

  // Rendering (confined to the ROI box).
  int rays_per_iteration = 256;
  int samples_per_ray = 16;
  double sample_band_voxels = 1.5;  ///< samples within this of the surface (and of the observed depth)
  double sharpness_voxels = 0.2;    ///< SDF-to-opacity logistic scale (NeuS s^-1)
  int sphere_trace_steps = 24;
  int max_rays = 20000;  ///< candidate rays kept from the ROI's keyframes
  /// Rays that cross the box to a surface beyond it where the TSDF has
  /// surface in the box on their way (what other views saw through), kept
  /// besides max_rays; 0: none.
  int free_space_rays = 4000;
  double free_space_share = 0.25;  ///< of each iteration's rays, when there are such rays
  int pixel_stride = 1;            ///< candidate pixels at the keyframe level

  // Loss (eq 10).
  double lambda_photo = 0.2;
  double lambda_depth = 1.0;
  double lambda_normal = 0.05;
  double lambda_eikonal = 0.05;
  double depth_huber_voxels = 0.5;  ///< depth residuals in voxels, Huber beyond this
  double photo_huber = 0.1;         ///< color residuals (in [0, 1]), Huber beyond this
  int regularizer_points = 128;     ///< points per iteration for the normal and eikonal terms

  // Optimizer (Adam, lazy on the grids: only entries a sample touched move).
  double learning_rate_grid = 0.02;
  double learning_rate_mlp = 0.005;
  int iterations = 150;            ///< cap per job
  double time_budget_ms = 1500.0;  ///< cap per job (cooperative: checked between slices)
  int slice_iterations = 1;        ///< iterations per scheduler slice (one is about 1-1.5 ms at 2 cm)
  /// Early stop: the smoothed loss improved by less than this share over
  /// the last `patience` iterations.
  double convergence_rel = 0.002;
  int patience = 25;

  // Write-back (eq 11).
  /// At most, a refined voxel is fused with this many times the weight it
  /// had in the snapshot (so it takes up to ratio / (1 + ratio) of the
  /// refined value); less where the TSDF's error is noise, not bias.
  double writeback_weight_ratio = 4.0;
  int bias_rays = 2048;  ///< rays rendered from the TSDF to tell its bias from noise
  /// Completion: voxels fusion never observed take the field's value where
  /// the keyframes' rays render better from the field (RoiRefiner::completes).
  bool completion = true;
  /// The weight falls linearly to 0 over this many voxels at the ROI border
  /// (no seam with the unrefined map around it).
  double border_blend_voxels = 2.0;
  /// The detail layer (detail.hpp) keeps the field's surface below the
  /// voxel size where the write-back gave the field at least this share of
  /// the voxel (ratio / (1 + ratio); 0.5: where the TSDF's error was found
  /// to be bias rather than noise). 1, the default, turns the layer off: at
  /// 0.5 it raised precision on the quality room's rods and edges but cost
  /// as much recall, and 0.1-0.3 points of F1 on the synthetic room.
  double detail_min_share = 1.0;
};

}  // namespace hxmap::alg
