// The detail layer of refined ROIs (detail.hpp): a rod thinner than the
// voxel spacing, which no interpolation of voxel-center values can show,
// comes out of the hybrid mesh at its true radius, and goes when the map
// under it changes; a detail that refines nothing leaves the map's own mesh
// as it was (no seam at the box).
#include <gtest/gtest.h>

#include <cmath>

#include "hxmap/implicit/detail.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "hxmap/tsdf/patch.hpp"

namespace hxmap::alg {
namespace {

constexpr float kVoxel = 0.02f, kMu = 0.06f;

TsdfParams params() {
  TsdfParams p;
  p.voxel_size_m = kVoxel;
  p.truncation_m = kMu;
  return p;
}

// A map whose voxels in [0, n) hold sdf(center) exactly, weight 1.
template <class Sdf>
TsdfMap exactMap(const Eigen::Vector3i& n, Sdf sdf) {
  TsdfMap map(params());
  TsdfPatch patch;
  for (int z = 0; z < n.z(); ++z) {
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x) {
        TsdfPatch::Entry e;
        e.voxel = Eigen::Vector3i(x, y, z);
        e.sdf_m = std::clamp(sdf(map.voxelCenter(e.voxel)), -kMu, kMu);
        e.weight = 1.0f;
        patch.entries.push_back(e);
      }
    }
  }
  applyPatch(map, patch);
  return map;
}

// The detail a perfectly trained field would give with full trust: the true
// distance at every node, the map's trilinear value as the snapshot.
// Its box spans the centres of voxels [first, first + n).
template <class Sdf>
RefinedDetail exactDetail(const TsdfMap& map, const Eigen::Vector3i& n, Sdf sdf,
                          const Eigen::Vector3i& first = Eigen::Vector3i::Zero()) {
  RefinedDetail d;
  d.grid.origin = map.voxelCenter(first);
  d.grid.cell = 0.5f * kVoxel;
  d.grid.nodes = 2 * (n - Eigen::Vector3i::Ones()) + Eigen::Vector3i::Ones();
  d.box = Eigen::AlignedBox3f(d.grid.origin, map.voxelCenter(first + n - Eigen::Vector3i::Ones()));
  d.refined_m.assign(d.grid.nodeCount(), NAN);
  d.snapshot_m.assign(d.grid.nodeCount(), NAN);
  size_t i = 0;
  for (int z = 0; z < d.grid.nodes.z(); ++z) {
    for (int y = 0; y < d.grid.nodes.y(); ++y) {
      for (int x = 0; x < d.grid.nodes.x(); ++x, ++i) {
        const Eigen::Vector3f p = d.grid.origin + d.grid.cell * Eigen::Vector3f(float(x), float(y), float(z));
        float tri = 0;
        if (!map.sample(p, 0.0f, tri)) continue;
        d.snapshot_m[i] = tri;
        d.refined_m[i] = std::clamp(sdf(p), -kMu, kMu);
        ++d.detailed_nodes;
      }
    }
  }
  return d;
}

TEST(RefinedDetail, HybridMeshShowsARodThinnerThanAVoxel) {
  // A rod of radius 7.5 mm along x, its axis halfway between voxel centers:
  // the nearest centers are 14 mm from the axis, all outside the rod.
  const Eigen::Vector3i n(15, 10, 10);
  const float r = 0.0075f;
  auto rod = [&](const Eigen::Vector3f& p) { return std::hypot(p.y() - 0.1f, p.z() - 0.1f) - r; };
  const TsdfMap map = exactMap(n, rod);
  MeshParams mp;
  mp.min_weight = 0.5;
  ASSERT_TRUE(extractMesh(map, mp).empty()) << "the voxel grid alone should miss the rod";

  auto detail = std::make_shared<RefinedDetail>(exactDetail(map, n, rod));
  ASSERT_FALSE(detail->empty());
  const TriangleMesh hybrid = extractHybridMesh(map, mp, {detail});
  ASSERT_FALSE(hybrid.empty());
  ASSERT_EQ(hybrid.colors.size(), hybrid.vertices.size());
  float worst = 0;
  for (const auto& v : hybrid.vertices) worst = std::max(worst, std::abs(rod(v)));
  EXPECT_LT(worst, 0.0015f) << "vertices off the rod's surface";
  // Half-voxel sampling of a circle of 1.5 cm: a polygon, most of the area.
  const double length = detail->box.sizes().x(), lateral = 2 * M_PI * r * length;
  EXPECT_GT(hybrid.surfaceArea(), 0.7 * lateral);
  EXPECT_LT(hybrid.surfaceArea(), 1.1 * lateral);

  // The scene changes after the job: the rod is taken away and the map,
  // fusing new frames, shows free space there. The detail is stale and
  // gives way to the map.
  const TsdfMap changed = exactMap(n, [](const Eigen::Vector3f&) { return kMu; });
  EXPECT_TRUE(extractHybridMesh(changed, mp, {detail}).empty());
}

TEST(RefinedDetail, ZeroDetailKeepsTheMapsMesh) {
  // A tilted plane: the detail box covers part of it and adds nothing, so
  // the hybrid mesh lies on the same plane with the same area (no seam).
  const Eigen::Vector3i n(16, 16, 16);
  const Eigen::Vector3f normal = Eigen::Vector3f(0.2f, 0.1f, 1.0f).normalized();
  auto plane = [&](const Eigen::Vector3f& p) { return normal.dot(p) - 0.15f; };
  const TsdfMap map = exactMap(n, plane);
  const MeshParams mp;
  const TriangleMesh base = extractMesh(map, mp);
  ASSERT_FALSE(base.empty());

  // The box lies inside the map, as a refined region does: on the map's
  // outermost voxel centres whether the map samples rests on the last bit
  // of the node's position (a fused multiply-add, as on arm64, rounds it
  // once where x86-64 rounds twice), and a node without a value leaves a seam.
  auto zero =
      std::make_shared<RefinedDetail>(exactDetail(map, Eigen::Vector3i(10, 10, 12), plane, Eigen::Vector3i(2, 2, 2)));
  // A plane is exact in trilinear: near the surface the refined values are
  // the map's own up to its storage rounding (farther, the truncation bends
  // the distance). Make them the map's exactly.
  size_t i = 0;
  for (int z = 0; z < zero->grid.nodes.z(); ++z) {
    for (int y = 0; y < zero->grid.nodes.y(); ++y) {
      for (int x = 0; x < zero->grid.nodes.x(); ++x, ++i) {
        const Eigen::Vector3f p = zero->grid.origin + zero->grid.cell * Eigen::Vector3f(float(x), float(y), float(z));
        if (std::abs(plane(p)) < 0.03f) {
          ASSERT_NEAR(zero->refined_m[i], zero->snapshot_m[i], 2e-4f);
        }
        zero->refined_m[i] = zero->snapshot_m[i];
      }
    }
  }
  const TriangleMesh hybrid = extractHybridMesh(map, mp, {zero});
  for (const auto& v : hybrid.vertices) ASSERT_NEAR(plane(v), 0.0f, 3e-4f);
  EXPECT_NEAR(hybrid.surfaceArea(), base.surfaceArea(), 0.01 * base.surfaceArea());

  // An empty detail (or none) is the map's own mesh.
  const TriangleMesh same = extractHybridMesh(map, mp, {std::make_shared<RefinedDetail>(), nullptr});
  EXPECT_EQ(same.triangles.size(), base.triangles.size());
}

}  // namespace
}  // namespace hxmap::alg
