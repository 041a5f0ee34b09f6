// The map cut into regions (cubes of region_blocks^3 TSDF blocks) for
// publishing updates: which regions changed since a revision, a snapshot of
// their blocks for meshing on another thread, and the mesh of one region in
// parts of bounded size.
//
// DESIGN: map updates go out as meshes of whole regions, not as deltas of
// triangles: a region's mesh is recomputed from its blocks and replaces the
// previous one, so a subscriber that missed updates (or joined late) is
// right again after the next version of each region, and the publisher keeps
// no per-subscriber state. Region meshes tile the full mesh exactly (each
// marching cube belongs to the block of its minimum corner); vertices on a
// region's +x/+y/+z faces are repeated in the neighbouring region's mesh.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "hxmap/geometry/mesh.hpp"
#include "hxmap/tsdf/params.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

using RegionKey = Eigen::Vector3i;

/// The region holding a block (floor division).
RegionKey regionOf(const BlockKey& block, int region_blocks);

/// Regions whose mesh a block written after `revision` (TsdfMap::changedSince)
/// may change: the block's own and, for a block on its region's -x/-y/-z
/// face, the neighbours that read it beyond their +x/+y/+z faces. Sorted
/// and unique.
std::vector<RegionKey> changedRegions(const TsdfMap& map, uint64_t revision, int region_blocks);

/// Regions holding at least one block, sorted and unique.
std::vector<RegionKey> occupiedRegions(const TsdfMap& map, int region_blocks);
/// The blocks region r's mesh reads (its blocks and the layer beyond its
/// +x/+y/+z faces) that are held out of memory (a memory budget): meshed
/// without them, the region would lack their surface. In z, y, x order.
std::vector<BlockKey> regionBlocksElsewhere(const TsdfMap& map, const RegionKey& region, int region_blocks);
/// Copies a block held out of memory (a block store's peek); false when it
/// no longer holds it.
using BlockReader = std::function<bool(const BlockKey&, VoxelBlock&)>;
/// Reads `keys` with `read` into `local` (a copy of regions to mesh);
/// returns how many did not read.
size_t readBlocksInto(TsdfMap& local, const std::vector<BlockKey>& keys, const BlockReader& read);

/// A map holding copies of the blocks of `regions` and of the blocks just
/// beyond their +x/+y/+z faces, which the regions' marching cubes read.
TsdfMap copyRegions(const TsdfMap& map, const std::vector<RegionKey>& regions, int region_blocks);

/// Marching-cubes mesh of one region of `map` (a full map or a copyRegions
/// snapshot holding the region).
TriangleMesh regionMesh(const TsdfMap& map, const RegionKey& region, int region_blocks, const MeshParams& params);

/// Cuts a mesh into parts of at most `max_triangles` triangles (at least 1),
/// each with its own vertices and colors; triangle order is kept. An empty
/// mesh gives no parts.
std::vector<TriangleMesh> splitMesh(const TriangleMesh& mesh, size_t max_triangles);

}  // namespace hxmap::alg
