// The block store's index against std::unordered_map: the same records
// after any mix of inserts, replacements and erasures (which shift slots
// back), through growth and shrinking.
#include <gtest/gtest.h>

#include <random>
#include <unordered_map>

#include "hxmap/mapfile/record_index.hpp"

namespace {
using hxmap::drv::RecordIndex;

void expectSame(const RecordIndex& index, const std::unordered_map<uint64_t, RecordIndex::Record>& reference) {
  ASSERT_EQ(index.size(), reference.size());
  size_t seen = 0;
  index.forEach([&](uint64_t key, const RecordIndex::Record& r) {
    ++seen;
    const auto it = reference.find(key);
    ASSERT_NE(it, reference.end()) << key;
    EXPECT_EQ(r.offset, it->second.offset);
    EXPECT_EQ(r.stored, it->second.stored);
    EXPECT_EQ(r.crc, it->second.crc);
    EXPECT_EQ(r.seen_through, it->second.seen_through);
  });
  EXPECT_EQ(seen, reference.size());
}

TEST(RecordIndex, HoldsWhatAHashMapHoldsThroughGrowthAndShrinking) {
  std::mt19937_64 rng(3);
  RecordIndex index;
  std::unordered_map<uint64_t, RecordIndex::Record> reference;
  EXPECT_FALSE(index.find(5).has_value());
  EXPECT_FALSE(index.erase(5));
  // Keys from a narrow range collide often: long probe runs to shift back.
  for (int round = 0; round < 3; ++round) {
    const uint64_t range = round == 0 ? 3000 : 400000;
    for (int i = 0; i < 60000; ++i) {
      const uint64_t key = rng() % range;
      if (rng() % 3 == 0) {
        EXPECT_EQ(index.erase(key), reference.erase(key) == 1);
      } else {
        const RecordIndex::Record r{rng() % (uint64_t{1} << 40), static_cast<uint32_t>(rng() % (1u << 31)),
                                    static_cast<uint32_t>(rng()), rng() % 2 == 0};
        index.set(key, r);
        reference[key] = r;
      }
    }
    expectSame(index, reference);
    for (uint64_t key = 0; key < 3000; ++key) EXPECT_EQ(index.contains(key), reference.count(key) == 1) << key;
  }
  // Nearly all out: the table shrinks and still finds the rest.
  const size_t grown = index.memoryBytes();
  std::vector<uint64_t> keys;
  for (const auto& [k, r] : reference) keys.push_back(k);
  for (size_t i = 10; i < keys.size(); ++i) {
    EXPECT_TRUE(index.erase(keys[i]));
    reference.erase(keys[i]);
  }
  EXPECT_LT(index.memoryBytes(), grown / 8);
  expectSame(index, reference);
  for (const auto& [k, r] : reference) {
    const auto found = index.find(k);
    ASSERT_TRUE(found.has_value());
    EXPECT_EQ(found->offset, r.offset);
  }
  // Compaction moves a record only when it is still where it was read.
  const uint64_t k = keys[0];
  index.moveIfAt(k, reference[k].offset + 1, 7);
  EXPECT_EQ(index.find(k)->offset, reference[k].offset);
  index.moveIfAt(k, reference[k].offset, 7);
  EXPECT_EQ(index.find(k)->offset, 7u);
  index.clear();
  EXPECT_EQ(index.size(), 0u);
  EXPECT_FALSE(index.contains(k));
}

TEST(RecordIndex, ARecordCostsFarLessThanAHashMapNode) {
  RecordIndex index;
  for (uint64_t k = 0; k < 100000; ++k) index.set(k * 2654435761u, RecordIndex::Record{k, 100, 0, false});
  // 24-byte slots, at most 70 % and (growing by two) at least 35 % full.
  EXPECT_LE(static_cast<double>(index.memoryBytes()) / 100000.0, 24.0 / 0.35);
  EXPECT_EQ(index.find(uint64_t{99999} * 2654435761u)->offset, 99999u);
}

}  // namespace
