#pragma once

namespace hxmap::alg {

/// Voxel-hashed TSDF map. Units in field names.
struct TsdfParams {
  double voxel_size_m = 0.02;
  double truncation_m = 0.08;       ///< mu: the band around the surface that is stored
  double max_weight = 64.0;         ///< fusion weight cap: keeps the map adaptive
  double max_integration_depth_m = 4.0;
  double min_confidence = 0.05;     ///< pixels below are not integrated
  /// Fusion reads every 2^level-th pixel of the depth image; -1 = automatic:
  /// 1 (half resolution) unless voxels at max_integration_depth_m would span
  /// less than half a pixel there (fx 525, 4 m: 1 for 1 and 2 cm voxels).
  int integration_level = -1;
  /// Pixel stride (at that level) when finding blocks to allocate; 0 =
  /// automatic, a third of the pixels a block spans at max_integration_depth_m.
  int allocation_stride_px = 0;
  /// Memory budget for the voxels, MiB (0 = none): a run moves the blocks
  /// farthest from the camera out to a block store on disk past it.
  double max_resident_mib = 0;
};

/// Raycasting the map into depth, normal and color images.
struct RaycastParams {
  double min_depth_m = 0.1;
  double max_depth_m = 5.0;
  double step_factor = 0.8;  ///< march step = factor * |sdf| (at least half a voxel)
  double min_weight = 0.0;   ///< voxels with no more fused weight than this are unknown (weights sum confidences in [0, 1])
};

/// Marching-cubes meshing.
struct MeshParams {
  double min_weight = 0.3;   ///< cubes with a corner of less fused weight are skipped
  bool with_colors = true;
};

}  // namespace hxmap::alg
