// Checkpoints of a run: what a killed run leaves on disk holds the map as
// of the last checkpoint, blocks moved out under a memory budget included.
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include "checkpoint.hpp"
#include "hxmap/mapfile/block_store.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::rt {
namespace {

// A checkpoint under a budget: the map's snapshot lacks the blocks moved
// out, and the checkpoint's mesh still holds their surface, read from the
// block store region by region; a block the store no longer holds leaves
// its region's last mesh until the next checkpoint.
TEST(Checkpoint, AMeshUnderAMemoryBudgetKeepsTheSurfaceOfBlocksMovedOut) {
  const test::SmallRoom room;
  alg::TsdfMap map(room.tsdf());
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  map.setBacking(store->get());
  auto observe = [&](int i) { return room.observe(i); };
  for (int i = 0; i < 60; i += 10) alg::integrate(map, observe(i));
  const alg::MeshParams mp;
  CheckpointMesher mesher(mp, [&](const alg::BlockKey& k, alg::VoxelBlock& b) { return (*store)->peek(k, b); });
  const auto checkpoint = [&] {
    MapCheckpoint c;
    c.map = std::make_shared<const alg::TsdfMap>(map.snapshot());
    return mesher.mesh(c);
  };
  const auto sameSurface = [](const alg::TriangleMesh& a, const alg::TriangleMesh& b) {
    EXPECT_EQ(a.triangles.size(), b.triangles.size());
    EXPECT_NEAR(a.surfaceArea(), b.surfaceArea(), 1e-6 * b.surfaceArea());
  };
  const alg::TriangleMesh whole = alg::extractMesh(map, mp);
  ASSERT_GT(whole.triangles.size(), 10000u);
  sameSurface(checkpoint(), whole);  // regions tile the mesh

  // A new view fused, then half the blocks moved out before the next
  // checkpoint: it still has the whole surface, as fused.
  alg::integrate(map, observe(90));
  const alg::TriangleMesh before_out = alg::extractMesh(map, mp);
  std::vector<int32_t> out;
  for (size_t b = 0; b < map.blockCount(); ++b) {
    if (map.key(b).x() < 0) out.push_back(static_cast<int32_t>(b));
  }
  ASSERT_GT(out.size(), map.blockCount() / 5);
  ASSERT_EQ(map.removeBlocks(out), 0u);
  EXPECT_LT(alg::extractMesh(map, mp).surfaceArea(), 0.9 * before_out.surfaceArea()) << "what is in memory";
  sameSurface(checkpoint(), before_out);
  EXPECT_EQ(mesher.regionsWaiting(), 0u);
  EXPECT_GT(mesher.blocksRead(), out.size() / 2);
  EXPECT_EQ(mesher.blocksUnread(), 0u);

  // A block the store no longer holds (taken back after the snapshot):
  // its regions keep their last mesh and wait for the next checkpoint.
  alg::integrate(map, observe(120));  // changes regions on both sides of the cut
  MapCheckpoint c;
  c.map = std::make_shared<const alg::TsdfMap>(map.snapshot());
  std::vector<alg::BlockKey> keys;
  map.blocksElsewhere().forEach([&](const alg::BlockKey& k) { keys.push_back(k); });
  for (const auto& k : keys) map.findOrAllocate(k);  // all back: the store is empty
  ASSERT_TRUE(map.blocksElsewhere().empty());
  mesher.mesh(c);
  EXPECT_GT(mesher.regionsWaiting(), 0u);
  EXPECT_GT(mesher.blocksUnread(), 0u);
  // The next checkpoint, every block in memory: the map's whole mesh.
  sameSurface(checkpoint(), alg::extractMesh(map, mp));
  EXPECT_EQ(mesher.regionsWaiting(), 0u);

  // A map rebuilt empty: no region left.
  map.clear();
  EXPECT_TRUE(checkpoint().empty());
}

}  // namespace
}  // namespace hxmap::rt
