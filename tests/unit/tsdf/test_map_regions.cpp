// Map regions for publishing updates: change tracking, region snapshots and
// meshes, and splitting meshes into bounded parts.
#include <gtest/gtest.h>

#include <array>
#include <map>
#include <set>

#include "hxmap/tsdf/map_regions.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "hxmap/tsdf/patch.hpp"

namespace hxmap::alg {
namespace {

// A sphere written straight into the voxels (radius 0.23 m at 2 cm voxels,
// off the region grid so it spans many regions, negative coordinates too).
TsdfMap sphereMap(const Eigen::Vector3f& center = {0.05f, -0.07f, 0.11f}, float radius = 0.23f) {
  TsdfParams p;
  p.voxel_size_m = 0.02;
  p.truncation_m = 0.08;
  TsdfMap map(p);
  const float mu = map.truncation();
  const Eigen::Vector3i lo = map.voxelOf(center - Eigen::Vector3f::Constant(radius + 2 * mu));
  const Eigen::Vector3i hi = map.voxelOf(center + Eigen::Vector3f::Constant(radius + 2 * mu));
  for (int z = lo.z(); z <= hi.z(); ++z) {
    for (int y = lo.y(); y <= hi.y(); ++y) {
      for (int x = lo.x(); x <= hi.x(); ++x) {
        const Eigen::Vector3i g(x, y, z);
        const float d = (map.voxelCenter(g) - center).norm() - radius;
        if (std::abs(d) > mu) continue;
        const BlockKey key(x >> 3, y >> 3, z >> 3);
        VoxelBlock& b = map.block(static_cast<size_t>(map.findOrAllocate(key)));
        const int i = VoxelBlock::index(x & 7, y & 7, z & 7);
        b.geo[i] = {d, 1.0f};
        b.color[i] = {static_cast<uint8_t>(x & 255), static_cast<uint8_t>(y & 255), static_cast<uint8_t>(z & 255), 0};
      }
    }
  }
  std::vector<int32_t> all(map.blockCount());
  for (size_t b = 0; b < all.size(); ++b) all[b] = static_cast<int32_t>(b);
  map.markChanged(all);
  return map;
}

bool keyLess(const Eigen::Vector3i& a, const Eigen::Vector3i& b) {
  return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
}

TEST(MapRegions, RegionOfFloorsNegativeBlocks) {
  EXPECT_EQ(regionOf(BlockKey(0, 3, 4), 4), RegionKey(0, 0, 1));
  EXPECT_EQ(regionOf(BlockKey(-1, -4, -5), 4), RegionKey(-1, -1, -2));
  EXPECT_EQ(regionOf(BlockKey(7, -8, 8), 1), RegionKey(7, -8, 8));
}

TEST(MapRegions, RegionMeshesTileTheFullMesh) {
  const TsdfMap map = sphereMap();
  const MeshParams mp;
  const TriangleMesh full = extractMesh(map, mp);
  ASSERT_GT(full.triangles.size(), 1000u);
  for (int rb : {1, 2, 4}) {
    const std::vector<RegionKey> regions = changedRegions(map, 0, rb);
    ASSERT_GT(regions.size(), 1u) << "region_blocks " << rb;
    size_t triangles = 0;
    double area = 0;
    for (const RegionKey& r : regions) {
      const TriangleMesh m = regionMesh(map, r, rb, mp);
      triangles += m.triangles.size();
      area += m.surfaceArea();
      // Every vertex lies in the region's cube (closed at the +faces, where
      // the last cubes end on the next region's first voxel centers).
      const float size = map.blockSize() * static_cast<float>(rb);
      const float half_voxel = 0.5f * map.voxelSize();
      for (const auto& v : m.vertices) {
        for (int a = 0; a < 3; ++a) {
          EXPECT_GE(v[a], r[a] * size + half_voxel - 1e-5f);
          EXPECT_LE(v[a], (r[a] + 1) * size + half_voxel + 1e-5f);
        }
      }
    }
    EXPECT_EQ(triangles, full.triangles.size()) << "region_blocks " << rb;
    EXPECT_NEAR(area, full.surfaceArea(), 1e-6 * full.surfaceArea()) << "region_blocks " << rb;
  }
}

TEST(MapRegions, SnapshotGivesTheSameRegionMeshes) {
  const TsdfMap map = sphereMap();
  const int rb = 2;
  std::vector<RegionKey> regions = changedRegions(map, 0, rb);
  regions.resize(regions.size() / 2);  // a subset, as after a partial update
  const TsdfMap snapshot = copyRegions(map, regions, rb);
  EXPECT_LT(snapshot.blockCount(), map.blockCount());
  for (const RegionKey& r : regions) {
    const TriangleMesh a = regionMesh(map, r, rb, MeshParams{});
    const TriangleMesh b = regionMesh(snapshot, r, rb, MeshParams{});
    ASSERT_EQ(a.triangles.size(), b.triangles.size());
    ASSERT_EQ(a.vertices.size(), b.vertices.size());
    for (size_t i = 0; i < a.vertices.size(); ++i) EXPECT_EQ(a.vertices[i], b.vertices[i]);
    EXPECT_EQ(a.colors, b.colors);
  }
}

TEST(MapRegions, ChangedRegionsFollowWrites) {
  TsdfMap map = sphereMap();
  const uint64_t r0 = map.revision();
  EXPECT_TRUE(changedRegions(map, r0, 4).empty());
  // A patch touching one voxel changes its region and, as its block is on
  // that region's -z face, the region below, whose marching cubes read it.
  TsdfPatch patch;
  TsdfPatch::Entry e;
  e.voxel = map.voxelOf(Eigen::Vector3f(0.05f + 0.23f, -0.07f, 0.11f));
  e.sdf_m = 0.0f;
  e.weight = 1.0f;
  patch.entries.push_back(e);
  applyPatch(map, patch);
  EXPECT_GT(map.revision(), r0);
  const std::vector<RegionKey> changed = changedRegions(map, r0, 4);
  const BlockKey block(e.voxel.x() >> 3, e.voxel.y() >> 3, e.voxel.z() >> 3);
  ASSERT_EQ(block.z() % 4, 0) << "the voxel's block is on its region's -z face";
  ASSERT_EQ(changed.size(), 2u);
  EXPECT_EQ(changed[0], regionOf(block, 4) - RegionKey(0, 0, 1));
  EXPECT_EQ(changed[1], regionOf(block, 4));
  EXPECT_TRUE(changedRegions(map, map.revision(), 4).empty());
  // Sorted and unique.
  const auto all = changedRegions(map, 0, 2);
  for (size_t i = 1; i < all.size(); ++i) EXPECT_TRUE(keyLess(all[i - 1], all[i]));
}

TEST(MapRegions, RemeshingTheChangedRegionsKeepsTheirMeshesTheFullMesh) {
  // A publisher keeps each region's mesh and re-meshes the changed regions
  // only; after an edit across region faces the kept meshes must still
  // make the whole map's mesh (the faces' neighbours included).
  TsdfMap map = sphereMap();
  const MeshParams mp;
  std::map<std::array<int, 3>, size_t> triangles;
  auto remesh = [&](const std::vector<RegionKey>& regions) {
    for (const RegionKey& r : regions) triangles[{r.x(), r.y(), r.z()}] = regionMesh(map, r, 4, mp).triangles.size();
  };
  remesh(changedRegions(map, 0, 4));
  const uint64_t r0 = map.revision();
  // Carve a slab one voxel thick on a plane of region faces (x = 0).
  TsdfPatch carve;
  for (int z = -20; z <= 20; ++z) {
    for (int y = -20; y <= 20; ++y) {
      TsdfPatch::Entry e;
      e.voxel = Eigen::Vector3i(0, y, z);
      int index = 0;
      if (map.blockOfVoxel(e.voxel, index) == nullptr) continue;
      e.sdf_m = map.truncation();
      e.weight = 1000.0f;
      carve.entries.push_back(e);
    }
  }
  ASSERT_GT(carve.entries.size(), 100u);
  applyPatch(map, carve);
  remesh(changedRegions(map, r0, 4));
  size_t total = 0;
  for (const auto& [key, n] : triangles) total += n;
  EXPECT_EQ(total, extractMesh(map, mp).triangles.size());
}

TEST(MapRegions, AReplacingMapIsChangedEverywhereAfterTheOldRevision) {
  // A loop closure replaces the map with one fused anew: a publisher that
  // followed the old map's revisions must see every block of the new one.
  TsdfMap old_map = sphereMap();
  for (int i = 0; i < 5; ++i) old_map.markChanged({0});
  TsdfMap replacement = sphereMap();
  ASSERT_LT(replacement.revision(), old_map.revision() + 1);
  EXPECT_TRUE(changedRegions(replacement, old_map.revision(), 4).empty()) << "the case the mark is for";
  replacement.markAllChanged(old_map.revision());
  EXPECT_GT(replacement.revision(), old_map.revision());
  EXPECT_EQ(changedRegions(replacement, old_map.revision(), 4), changedRegions(replacement, 0, 4));
  EXPECT_FALSE(changedRegions(replacement, 0, 4).empty());
  EXPECT_TRUE(changedRegions(replacement, replacement.revision(), 4).empty());
}

TEST(MapRegions, SplitMeshKeepsEveryTriangleWithinBounds) {
  const TsdfMap map = sphereMap();
  const TriangleMesh full = extractMesh(map, MeshParams{});
  for (size_t max_tris : {size_t{1}, size_t{100}, size_t{997}, full.triangles.size(), full.triangles.size() + 5}) {
    const auto parts = splitMesh(full, max_tris);
    ASSERT_EQ(parts.size(), (full.triangles.size() + max_tris - 1) / max_tris) << max_tris;
    size_t triangles = 0;
    double area = 0;
    for (const auto& p : parts) {
      EXPECT_LE(p.triangles.size(), max_tris);
      EXPECT_EQ(p.colors.size(), p.vertices.size());
      for (const auto& t : p.triangles) {
        for (int c = 0; c < 3; ++c) ASSERT_LT(static_cast<size_t>(t[c]), p.vertices.size());
      }
      // Only the vertices the part's triangles use.
      std::set<int> used;
      for (const auto& t : p.triangles) used.insert({t[0], t[1], t[2]});
      EXPECT_EQ(used.size(), p.vertices.size());
      triangles += p.triangles.size();
      area += p.surfaceArea();
    }
    EXPECT_EQ(triangles, full.triangles.size());
    EXPECT_NEAR(area, full.surfaceArea(), 1e-6 * full.surfaceArea());
  }
  EXPECT_TRUE(splitMesh(TriangleMesh{}, 10).empty());
}

}  // namespace
}  // namespace hxmap::alg
