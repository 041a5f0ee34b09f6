// Marching cubes over the allocated blocks. The triangle table is generated
// at start-up from first principles (cube faces walked counter-clockwise,
// each face's crossings joined so that negative corners are cut off
// separately, the joined segments chained into loops and fanned), which makes
// the ambiguous-face rule explicit and the surface watertight between cubes.
#pragma once

#include <array>
#include <vector>

#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/mesh.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

/// Triangles of one cube configuration as cube-edge indices, 3 per triangle.
/// Corner c sits at (c & 1, c >> 1 & 1, c >> 2 & 1); edge e joins
/// kCubeEdges[e][0] and kCubeEdges[e][1]; bit c of the configuration is set
/// when corner c is inside (sdf < 0).
const std::vector<int>& marchingCubesTriangles(int configuration);
extern const std::array<std::array<int, 2>, 12> kCubeEdges;

/// Mesh of the zero level set in world coordinates, vertices shared between
/// neighbouring cubes, colors from the voxels when params.with_colors.
TriangleMesh extractMesh(const TsdfMap& map, const MeshParams& params);
/// The same over the given blocks only (their +x/+y/+z neighbours are read
/// for the cubes on those faces). Each cube belongs to the block of its
/// minimum corner, so the meshes of disjoint block sets tile the full mesh.
TriangleMesh extractMesh(const TsdfMap& map, const MeshParams& params, const std::vector<int32_t>& blocks);

/// Marching cubes over a dense grid of SDF samples (x fastest), with
/// `origin` the position of sample (0, 0, 0) and `spacing` between samples.
/// Samples that are NaN are treated as unknown (their cubes are skipped).
TriangleMesh extractMeshDense(const std::vector<float>& sdf, const Eigen::Vector3i& dims,
                              const Eigen::Vector3f& origin, float spacing);

}  // namespace hxmap::alg
