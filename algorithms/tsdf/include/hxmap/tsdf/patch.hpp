// Corrections to the map computed away from it (ROI refinement works on a
// snapshot): per voxel a signed distance, optionally a color, and the
// confidence to give them.
// DESIGN: a patch is fused like an observation (weighted running average,
// weight capped), not written over the voxel: frames fused since the
// snapshot are kept, and applying patches commutes with fusing frames.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

struct TsdfPatch {
  struct Entry {
    Eigen::Vector3i voxel;  ///< global voxel coordinates
    float sdf_m = 0;        ///< clamped to the truncation band when applied
    float weight = 0;       ///< confidence of the correction (> 0)
    uint8_t rgb[3] = {0, 0, 0};
    bool has_color = false;  ///< blend rgb into the voxel's color as well
    /// Free space seen through: flags the voxel kVoxelSeenThrough when the
    /// fused result is outside the surface. (Any entry whose result is
    /// inside clears the flag.)
    bool seen_through = false;
  };
  std::vector<Entry> entries;
};

struct PatchStats {
  size_t applied = 0;
  size_t rejected = 0;          ///< non-finite values or weight <= 0
  size_t blocks_allocated = 0;  ///< corrections outside the allocated map
  size_t seen_through = 0;      ///< voxels flagged kVoxelSeenThrough
};

/// Fuses the patch into the map (the map's writer calls this, between frames).
PatchStats applyPatch(TsdfMap& map, const TsdfPatch& patch);

}  // namespace hxmap::alg
