// The memory budget: blocks moved out to the block store on disk and
// brought back leave the TSDF exactly as it was, and a run under a budget
// keeps its voxels within it while the camera moves on.
#include <atomic>
#include <cstring>
#include <random>
#include <thread>

#include <gtest/gtest.h>

#include "hxmap/frontend/frontend.hpp"
#include "hxmap/mapfile/block_store.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::rt {
namespace {

size_t sameBlocks(const alg::TsdfMap& a, const alg::TsdfMap& b) {
  size_t same = 0;
  for (size_t i = 0; i < a.blockCount(); ++i) {
    const int32_t j = b.find(a.key(i));
    if (j < 0) continue;
    const alg::VoxelBlock& x = a.block(i);
    const alg::VoxelBlock& y = b.block(static_cast<size_t>(j));
    same += std::memcmp(x.geo, y.geo, sizeof x.geo) == 0 && std::memcmp(x.color, y.color, sizeof x.color) == 0 &&
            std::memcmp(x.stats, y.stats, sizeof x.stats) == 0 && x.seen_through == y.seen_through;
  }
  return same;
}

TEST(MemoryBudget, BlocksMovedOutAndBroughtBackLeaveTheTsdfAndItsStatisticsIdentical) {
  alg::TsdfParams p;
  alg::TsdfMap map(p);
  std::mt19937 rng(3);
  for (int x = -5; x < 5; ++x) {
    for (int y = -5; y < 5; ++y) {
      alg::VoxelBlock& b = map.block(static_cast<size_t>(map.findOrAllocate({x, y, 0})));
      for (int v = 0; v < alg::kBlockVoxels; ++v) {
        b.geo[v] = {static_cast<float>(rng() % 1000) * 1e-4f, static_cast<float>(rng() % 64)};
        b.color[v] = {static_cast<uint8_t>(rng()), 1, 2, 0};
        b.stats[v] = {static_cast<uint32_t>(rng() % 50), 0.01f, 0.002f};
      }
      b.seen_through = (x + y) % 2 == 0;
    }
  }
  const alg::TsdfMap before = map;
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  map.setBacking(store->get());
  std::vector<int32_t> out;
  for (int32_t i = 0; i < 100; i += 3) out.push_back(i);
  EXPECT_EQ(map.removeBlocks(out), 0u);
  EXPECT_EQ(map.blockCount(), 100u - out.size());
  EXPECT_EQ(map.blocksElsewhere().size(), out.size());
  EXPECT_EQ((*store)->stats().blocks, out.size());
  EXPECT_EQ(sameBlocks(map, before), map.blockCount()) << "the blocks that stayed (some moved) are unchanged";
  for (int32_t i = 0; i < 100; i += 3) EXPECT_TRUE(map.heldElsewhere(before.key(static_cast<size_t>(i))));
  (*store)->flush();  // on disk, compressed: what comes back is read from the file
  EXPECT_EQ((*store)->stats().queued, 0u);
  EXPECT_GT((*store)->stats().file_bytes, 0u);
  // Back, as fusion would bring them: by their keys.
  for (int32_t i = 0; i < 100; i += 3) map.findOrAllocate(before.key(static_cast<size_t>(i)));
  EXPECT_EQ(map.blockCount(), 100u);
  EXPECT_EQ(map.blocksElsewhere().size(), 0u);
  EXPECT_EQ(map.blocksTakenBack(), out.size());
  EXPECT_EQ(sameBlocks(map, before), 100u);
  EXPECT_EQ((*store)->stats().blocks, 0u);
}

TEST(MemoryBudget, FusionDeIntegrationAndWriteBackIntoBlocksMovedOutMeetTheirVoxels) {
  // Pose feedback re-integrates keyframes (de-integrate, fuse again) and a
  // refinement job's write-back lands in blocks the budget may have moved
  // out since the job's snapshot: each must find the voxels it left, not
  // empty blocks. Both maps take the same steps; one has every block moved
  // out before each.
  const test::SmallRoom room;
  const Trajectory& traj = room.traj;
  alg::TsdfMap kept(room.tsdf()), moved(room.tsdf());
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  moved.setBacking(store->get());
  auto observe = [&](int i, const Eigen::Isometry3d& T) { return room.observe(i, &T); };
  auto allOut = [&] {
    std::vector<int32_t> all(moved.blockCount());
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int32_t>(i);
    EXPECT_EQ(moved.removeBlocks(all), 0u);
    EXPECT_EQ(moved.blockCount(), 0u);
  };
  const auto a = observe(0, traj[0].T_world_cam), b = observe(12, traj[12].T_world_cam);
  for (alg::TsdfMap* m : {&kept, &moved}) {
    alg::integrate(*m, a);
    alg::integrate(*m, b);
  }
  const size_t blocks = kept.blockCount();
  // Re-integration of b at a corrected pose (feedback).
  Eigen::Isometry3d corrected = traj[12].T_world_cam;
  corrected.translation() += Eigen::Vector3d(0.01, -0.005, 0.0);
  const auto b_corrected = observe(12, corrected);
  allOut();
  alg::deintegrate(moved, b);
  alg::deintegrate(kept, b);
  allOut();
  alg::integrate(moved, b_corrected);
  alg::integrate(kept, b_corrected);
  // A write-back (refinement) over voxels of the surface.
  alg::TsdfPatch patch;
  for (size_t i = 0; i < kept.blockCount(); i += 7) {
    const alg::BlockKey k = kept.key(i);
    for (int v = 0; v < 8; ++v) {
      alg::TsdfPatch::Entry e;
      e.voxel = k * 8 + Eigen::Vector3i(v, (v * 3) & 7, (v * 5) & 7);
      e.sdf_m = 0.004f * static_cast<float>(v - 4);
      e.weight = 2.0f;
      e.has_color = v % 2 == 0;
      e.rgb[0] = 200;
      patch.entries.push_back(e);
    }
  }
  allOut();
  const auto moved_stats = alg::applyPatch(moved, patch);
  const auto kept_stats = alg::applyPatch(kept, patch);
  EXPECT_EQ(moved_stats.applied, kept_stats.applied);
  // Every block back: the two maps are the same, voxel for voxel.
  for (const Eigen::Vector3i& k : moved.blocksElsewhere().keys()) moved.findOrAllocate(k);
  EXPECT_EQ(moved.blocksLostInBacking(), 0u);
  ASSERT_EQ(moved.blockCount(), kept.blockCount());
  EXPECT_GE(kept.blockCount(), blocks);
  EXPECT_EQ(sameBlocks(moved, kept), kept.blockCount());
}

TEST(MemoryBudget, BlocksTakenBackWhileTheWriterIsAtWorkOrReadAheadAreTheBlocksPutAndAClearDropsAll) {
  // The store's writer compresses and writes behind put(): a block taken
  // back at once comes from its queue, one taken later from the file,
  // some while being written; each must be the block put, once.
  alg::TsdfParams p;
  alg::TsdfMap map(p);
  std::mt19937 rng(5);
  constexpr int kBlocks = 600;
  for (int i = 0; i < kBlocks; ++i) {
    alg::VoxelBlock& b = map.block(static_cast<size_t>(map.findOrAllocate({i % 30, i / 30, 1})));
    for (int v = 0; v < alg::kBlockVoxels; ++v) {
      b.geo[v] = {static_cast<float>(rng() % 1000) * 1e-4f, static_cast<float>(rng() % 64)};
      b.color[v] = {static_cast<uint8_t>(rng()), static_cast<uint8_t>(i), 2, 0};
      b.stats[v] = {static_cast<uint32_t>(rng() % 50), 0.01f * static_cast<float>(i), 0.002f};
    }
  }
  const alg::TsdfMap before = map;
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  map.setBacking(store->get());
  for (int round = 0; round < 3; ++round) {
    std::vector<int32_t> all(map.blockCount());
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int32_t>(i);
    EXPECT_EQ(map.removeBlocks(all), 0u);
    // Meanwhile another thread peeks at them (a checkpoint): each block it
    // gets is the block put, whether from the queue or the file, and
    // peeking takes none away.
    size_t peeked = 0, peeked_wrong = 0;
    std::atomic<bool> first_peeked{false};
    std::thread peeker([&] {
      alg::VoxelBlock b;
      for (int i = kBlocks - 1; i >= 0; --i) {
        const size_t k = static_cast<size_t>(i);
        const bool held = (*store)->peek(before.key(k), b);
        first_peeked.store(true);
        if (!held) continue;  // taken back already
        ++peeked;
        const alg::VoxelBlock& x = before.block(k);
        peeked_wrong +=
            std::memcmp(x.geo, b.geo, sizeof x.geo) != 0 || std::memcmp(x.stats, b.stats, sizeof x.stats) != 0;
      }
    });
    while (!first_peeked.load()) std::this_thread::yield();  // its first peek finds every block held
    // Every 7th back at once (most still queued), then the rest in order
    // while the writer works through them.
    for (int i = 0; i < kBlocks; i += 7) map.findOrAllocate(before.key(static_cast<size_t>(i)));
    if (round == 1) (*store)->flush();
    for (int i = 0; i < kBlocks; ++i) map.findOrAllocate(before.key(static_cast<size_t>(i)));
    peeker.join();
    EXPECT_GT(peeked, 0u) << "round " << round;
    EXPECT_EQ(peeked_wrong, 0u) << "round " << round;
    ASSERT_EQ(map.blockCount(), static_cast<size_t>(kBlocks));
    EXPECT_EQ(sameBlocks(map, before), static_cast<size_t>(kBlocks)) << "round " << round;
    EXPECT_EQ((*store)->stats().blocks, 0u);
    EXPECT_EQ(map.blocksLostInBacking(), 0u);
  }
  // Read ahead (the predicted view's hint): every other block, while the
  // writer still has some to write; those come back from the read-ahead.
  {
    std::vector<int32_t> all(map.blockCount());
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int32_t>(i);
    EXPECT_EQ(map.removeBlocks(all), 0u);
    std::vector<alg::BlockKey> hint;
    for (int i = 0; i < kBlocks; i += 2) hint.push_back(before.key(static_cast<size_t>(i)));
    (*store)->prefetch(hint);  // only blocks already on disk are read ahead
    (*store)->flush();
    (*store)->prefetch(hint);
    (*store)->flush();
    for (const alg::BlockKey& k : hint) EXPECT_TRUE((*store)->ready(k));
    EXPECT_FALSE((*store)->ready(before.key(1)));
    EXPECT_EQ((*store)->stats().read_ahead, hint.size());
    for (int i = 0; i < kBlocks; ++i) map.findOrAllocate(before.key(static_cast<size_t>(i)));
    EXPECT_EQ(sameBlocks(map, before), static_cast<size_t>(kBlocks)) << "read ahead";
    EXPECT_EQ((*store)->stats().read_ahead_used, hint.size());
  }
  const drv::BlockStoreStats s = (*store)->stats();
  EXPECT_EQ(s.put, 4u * kBlocks);
  EXPECT_EQ(s.taken, 4u * kBlocks);
  EXPECT_EQ(s.read_failures, 0u);
  // A clear while blocks are queued and being written: none comes back.
  std::vector<int32_t> half;
  for (int32_t i = 0; i < kBlocks; i += 2) half.push_back(i);
  std::vector<alg::BlockKey> half_keys;
  for (int32_t i : half) half_keys.push_back(map.key(static_cast<size_t>(i)));
  map.removeBlocks(half);
  (*store)->clear();
  (*store)->flush();
  EXPECT_EQ((*store)->stats().blocks, 0u);
  alg::VoxelBlock out;
  for (const alg::BlockKey& k : half_keys) EXPECT_FALSE((*store)->take(k, out));
}

TEST(MemoryBudget, ARunUnderABudgetStaysWithinItAndEndsWithTheMapOfARunWithout) {
  const alg::PinholeCamera cam{262.5, 262.5, 159.75, 119.75, 320, 240, {0, 0, 0, 0, 0}};
  drv::SyntheticParams sp;
  sp.frames = 90;
  sp.camera = cam;
  sp.trajectory = "orbit";
  sp.scale = 3.0;  // a room 12 m across: the camera sees a part of it at a time
  const Trajectory truth = drv::syntheticTrajectory(sp);
  const drv::SyntheticScene scene = drv::SyntheticScene::room().scaled(3.0f);
  FrontendParams params;
  params.quality_enabled = false;  // refinement writes back from snapshots of what is in memory
  params.refine.enabled = false;
  params.loop_closure.enabled = false;
  params.relocalization.enabled = false;
  // Poses given: both runs fuse the same frames at the same poses.
  Frontend free(cam, params);
  params.tsdf.max_resident_mib = 6.0;
  Frontend budgeted(cam, params);
  // One block a frame at most, unless the frame would end over the budget:
  // the budget holds all the same.
  params.max_evictions_per_frame = 1;
  Frontend tight(cam, params);
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  budgeted.setBlockBacking(store->get());
  auto tight_store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(tight_store) << tight_store.message();
  tight.setBlockBacking(tight_store->get());
  const size_t budget = 6 << 20;
  size_t most = 0, most_tight = 0;
  for (int i = 0; i < sp.frames; ++i) {
    const Eigen::Isometry3d& T = truth[static_cast<size_t>(i)].T_world_cam;
    RgbdFrame f = test::syntheticFrame(scene, cam, T, true, i);
    f.stamp_ns = truth[static_cast<size_t>(i)].stamp_ns;
    free.process(f, &T);
    budgeted.process(f, &T);
    tight.process(f, &T);
    most = std::max(most, budgeted.map().memory().bytes);
    most_tight = std::max(most_tight, tight.map().memory().bytes);
  }
  EXPECT_LE(most_tight, budget) << "one block a frame, and what the budget needs";
  EXPECT_EQ(tight.memoryCounters().frames_over_budget, 0u);
  tight.restoreEvicted();
  const MemoryCounters m = budgeted.memoryCounters();
  std::printf("budget 6 MiB: free run %.1f MiB; resident at most %.2f MiB, %llu moved out, %llu back\n",
              static_cast<double>(free.map().memory().bytes) / (1 << 20), static_cast<double>(most) / (1 << 20),
              static_cast<unsigned long long>(m.evicted), static_cast<unsigned long long>(m.taken_back));
  EXPECT_GT(free.map().memory().bytes, budget) << "the scene needs more than the budget";
  EXPECT_LE(most, budget) << "resident voxels after each frame";
  EXPECT_EQ(m.frames_over_budget, 0u);
  EXPECT_GT(m.evicted, 50u);
  EXPECT_EQ(m.lost, 0u);
  budgeted.restoreEvicted();
  ASSERT_EQ(budgeted.map().blockCount(), free.map().blockCount());
  EXPECT_EQ(sameBlocks(free.map(), budgeted.map()), free.map().blockCount())
      << "blocks moved out and back: the same map, bit for bit";
  EXPECT_EQ(sameBlocks(free.map(), tight.map()), free.map().blockCount());
}

}  // namespace
}  // namespace hxmap::rt
