// Corrections to the map computed away from it (ROI refinement works on a
// snapshot): per voxel a signed distance and the confidence to give it.
// DESIGN: a patch is fused like an observation (weighted running average,
// weight capped), not written over the voxel: frames fused since the
// snapshot are kept, and applying patches commutes with fusing frames.
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Core>

#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

struct TsdfPatch {
  struct Entry {
    Eigen::Vector3i voxel;  ///< global voxel coordinates
    float sdf_m = 0;        ///< clamped to the truncation band when applied
    float weight = 0;       ///< confidence of the correction (> 0)
  };
  std::vector<Entry> entries;
};

struct PatchStats {
  size_t applied = 0;
  size_t rejected = 0;          ///< non-finite values or weight <= 0
  size_t blocks_allocated = 0;  ///< corrections outside the allocated map
};

/// Fuses the patch into the map (the map's writer calls this, between frames).
PatchStats applyPatch(TsdfMap& map, const TsdfPatch& patch);

}  // namespace hxmap::alg
