// Sub-voxel detail of a refined ROI, and the hybrid mesh that shows it.
//
// DESIGN: the write-back (eq 11) fuses the trained field into the TSDF at
// voxel centers. That is not enough for the regions refinement exists for:
// (1) a voxel grid cannot hold a shape smaller than its spacing (a 1.5 cm
// rod at 2 cm voxels has no voxel center inside it, so no interpolation of
// values at the centers shows it, however well the field learned it), and
// (2) fusion keeps averaging new frames into those voxels, and where the
// TSDF's error is systematic (a thin part eroded or smeared, an occlusion
// edge bled) the frames carry the same error back in. On the quality room at
// 2 cm voxels the rods' mesh precision at 1 cm was 42 % before refinement
// and 41 % at the end of the run with write-backs. So each job also keeps,
// on its field's fine grid (half a voxel apart at the default
// fine_per_voxel 2), the refined signed distance
//
//   b(p) = t(p) + alpha(p) (s(p) - t(p))
//
// with t the snapshot's trilinear TSDF, s the trained field truncated to mu
// and alpha the share the write-back gave the field there (ratio / (1 +
// ratio)), where alpha reaches ImplicitParams::detail_min_share (the
// TSDF's error there was bias, not noise; where it was noise the field,
// fit to a few keyframes, would only add their noise below the voxel size:
// at 1 cm voxels, a noisy wall patch lost 5 points of precision with no
// threshold). alpha is 0 at the ROI border, so b meets the map without a
// seam. The hybrid mesh meshes b inside the ROI, node by node while the map
// there still agrees with the snapshot: where the current TSDF moved
// farther from t than the write-back itself moves it (|now - t| > |b - t| +
// half a voxel), something changed since the job (the scene, a pose
// correction) and the current TSDF is used.
// Measured (bench_refine, 2 cm voxels, detail_min_share 0.5, against the
// map after the write-backs): inside the ROIs precision 70.0 -> 72.7 %,
// rods 43 -> 46 %, board edges 56 -> 58 %, recall 63.9 -> 60.9 %: F1 0.5
// points lower, and 0.1-0.3 points lower on the synthetic room, hence off
// by default. Most of the rods' remaining error is surface the TSDF grows
// 2-8 cm behind them, in their shadow, where none of the job's training
// rays reaches (the views that saw through it are older than the job's
// keyframes) and the field is not constrained.
#pragma once

#include <memory>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/geometry/mesh.hpp"
#include "hxmap/implicit/neural_field.hpp"
#include "hxmap/tsdf/params.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

struct RefinedDetail {
  GridLayout grid;                ///< the field's fine grid, one channel
  Eigen::AlignedBox3f box;        ///< where the detail applies (the field's box)
  std::vector<float> refined_m;   ///< b per node, NaN = no detail
  std::vector<float> snapshot_m;  ///< t per node (meaningful where refined_m is set)
  size_t detailed_nodes = 0;      ///< nodes with a refined value

  bool empty() const { return detailed_nodes == 0; }
  size_t memoryBytes() const { return (refined_m.size() + snapshot_m.size()) * sizeof(float); }
  /// The hybrid signed distance at node n given the map's current value
  /// there (NaN: none).
  float hybridAt(size_t n, float now_m, float voxel_m) const;
};

/// The map's mesh with each detail's box meshed at the detail's resolution
/// (marching cubes over its nodes, hybridAt of the map's trilinear SDF). A triangle belongs to the last detail whose
/// box holds its centroid, else to the map's own mesh; `details` run oldest first. Colors (params.with_colors) are the
/// map's, sampled at the vertices.
TriangleMesh extractHybridMesh(const TsdfMap& map, const MeshParams& params,
                               const std::vector<std::shared_ptr<const RefinedDetail>>& details);

}  // namespace hxmap::alg
