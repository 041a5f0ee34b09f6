// BlockKeySet against std::set: the same keys in, the same keys out, at
// negative and positive coordinates and across region borders.
#include <gtest/gtest.h>

#include <random>
#include <set>
#include <tuple>

#include "hxmap/tsdf/block_key_set.hpp"

namespace {
using hxmap::alg::BlockKeySet;
using Key = std::tuple<int, int, int>;

Key tupleOf(const Eigen::Vector3i& k) { return {k.x(), k.y(), k.z()}; }

std::set<Key> contents(const BlockKeySet& set) {
  std::set<Key> out;
  set.forEach([&](const Eigen::Vector3i& k) { EXPECT_TRUE(out.insert(tupleOf(k)).second); });
  return out;
}

TEST(BlockKeySet, HoldsWhatASetOfKeysHolds) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> coord(-40, 40);
  BlockKeySet set;
  std::set<Key> reference;
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3i k(coord(rng), coord(rng), coord(rng));
    if (rng() % 3 == 0) {
      EXPECT_EQ(set.erase(k), reference.erase(tupleOf(k)) == 1);
    } else {
      EXPECT_EQ(set.insert(k), reference.insert(tupleOf(k)).second);
    }
  }
  EXPECT_EQ(set.size(), reference.size());
  EXPECT_EQ(contents(set), reference);
  for (int x = -41; x <= 41; x += 3) {
    for (int y = -41; y <= 41; y += 5) {
      EXPECT_EQ(set.contains({x, y, 7}), reference.count({x, y, 7}) == 1) << x << " " << y;
    }
  }
  // Far from the origin, at the packing's limits.
  const Eigen::Vector3i far(-(1 << 20), (1 << 20) - 1, -5);
  EXPECT_TRUE(set.insert(far));
  EXPECT_TRUE(set.contains(far));
  EXPECT_FALSE(set.contains(Eigen::Vector3i(-(1 << 20), (1 << 20) - 1, -6)));
  EXPECT_TRUE(set.erase(far));
  // Every key out: nothing left, no region either.
  for (const Key& k : reference) EXPECT_TRUE(set.erase({std::get<0>(k), std::get<1>(k), std::get<2>(k)}));
  EXPECT_TRUE(set.empty());
  EXPECT_EQ(contents(set).size(), 0u);
}

TEST(BlockKeySet, ARegionTestSkipsWholeRegions) {
  BlockKeySet set;
  for (int x = -20; x < 20; ++x) set.insert({x, 3, -1});  // regions x in [-24, 24) by 8
  std::set<int> xs;
  std::vector<Eigen::Vector3i> asked;
  set.forEachIn(
      [&](const Eigen::Vector3i& lo) {
        asked.push_back(lo);
        return lo.x() >= 0;
      },
      [&](const Eigen::Vector3i& k) { xs.insert(k.x()); });
  EXPECT_EQ(asked.size(), 6u);  // x in -20..19: the regions from -24, -16, -8, 0, 8 and 16
  for (const Eigen::Vector3i& lo : asked) {
    EXPECT_EQ(lo.y(), 0);
    EXPECT_EQ(lo.z(), -8);
    EXPECT_EQ(lo.x() % 8, 0);
  }
  EXPECT_EQ(xs.size(), 20u);
  EXPECT_EQ(*xs.begin(), 0);
  EXPECT_EQ(*xs.rbegin(), 19);
}

TEST(BlockKeySet, CostsFarLessThanAHashSetOnASurface) {
  BlockKeySet set;
  for (int x = 0; x < 400; ++x) {
    for (int z = 0; z < 100; ++z) set.insert({x, 5, z});  // a wall of 40 000 blocks
  }
  EXPECT_EQ(set.size(), 40000u);
  // A node-based hash set of 64-bit keys takes at least 32 bytes a key.
  EXPECT_LT(static_cast<double>(set.memoryBytes()) / 40000.0, 4.0);
}

}  // namespace
