// The TSDF as an OpenVDB file (what VDB-based mapping tools and Blender
// open): a level-set grid "sdf" (meters, background the truncation), a
// grid "weight" and a grid "color" (RGB in 0..1), holding the observed
// voxels. OpenVDB puts voxel (i, j, k) at (i, j, k) * voxel size; hxmap's
// voxel centers are at ((i, j, k) + 0.5) * voxel size, so the grids'
// transform carries that half-voxel offset: world positions agree.
#pragma once

#include <cstddef>
#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt {

struct VdbExport {
  std::string grids;  ///< the grids' names
  size_t voxels = 0;  ///< observed voxels written
  size_t bytes = 0;
};

/// Writes `map` to `path` (atomically: a temporary file renamed over it).
/// An error when this build has no OpenVDB (libopenvdb-dev).
Expected<VdbExport> exportVdb(const std::string& path, const alg::TsdfMap& map);

}  // namespace hxmap::rt
