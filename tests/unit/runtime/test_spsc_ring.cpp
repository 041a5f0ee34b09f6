#include <gtest/gtest.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "hxmap/ring/latest_slot.hpp"
#include "hxmap/ring/spsc_ring.hpp"

namespace hxmap::rt {
namespace {

TEST(SpscRing, FifoFullAndEmpty) {
  SpscRing<int> ring(3);
  EXPECT_EQ(ring.capacity(), 3u);
  int out = -1;
  EXPECT_FALSE(ring.tryPop(out));
  EXPECT_TRUE(ring.tryPush(1));
  EXPECT_TRUE(ring.tryPush(2));
  EXPECT_TRUE(ring.tryPush(3));
  EXPECT_FALSE(ring.tryPush(4)) << "a full ring rejects";
  EXPECT_EQ(ring.sizeApprox(), 3u);
  ASSERT_TRUE(ring.tryPop(out));
  EXPECT_EQ(out, 1);
  EXPECT_TRUE(ring.tryPush(4)) << "wraps around";
  for (int want : {2, 3, 4}) {
    ASSERT_TRUE(ring.tryPop(out));
    EXPECT_EQ(out, want);
  }
  EXPECT_FALSE(ring.tryPop(out));
  EXPECT_TRUE(ring.emptyApprox());
}

TEST(SpscRing, RejectsZeroCapacity) { EXPECT_THROW(SpscRing<int>(0), std::invalid_argument); }

// Counts live instances: every constructed element is destroyed exactly once,
// whether popped or left in the ring at destruction.
struct Counted {
  static inline int live = 0;
  explicit Counted(int v = 0) : value(v) { ++live; }
  Counted(const Counted& o) : value(o.value) { ++live; }
  Counted(Counted&& o) noexcept : value(o.value) { ++live; }
  Counted& operator=(const Counted&) = default;
  Counted& operator=(Counted&&) = default;
  ~Counted() { --live; }
  int value;
};

TEST(SpscRing, DestroysWhatItHolds) {
  Counted::live = 0;
  {
    SpscRing<Counted> ring(4);
    EXPECT_EQ(Counted::live, 0) << "no element constructed up front";
    ASSERT_TRUE(ring.emplace(1));
    ASSERT_TRUE(ring.emplace(2));
    ASSERT_TRUE(ring.emplace(3));
    EXPECT_EQ(Counted::live, 3);
    Counted out;
    ASSERT_TRUE(ring.tryPop(out));
    EXPECT_EQ(out.value, 1);
    EXPECT_EQ(Counted::live, 3);  // two queued + out
  }
  EXPECT_EQ(Counted::live, 0) << "the ring destroyed the two it still held";
}

TEST(SpscRing, MoveOnlyElements) {
  SpscRing<std::unique_ptr<std::string>> ring(2);
  ASSERT_TRUE(ring.tryPush(std::make_unique<std::string>("frame")));
  std::unique_ptr<std::string> out;
  ASSERT_TRUE(ring.tryPop(out));
  ASSERT_TRUE(out);
  EXPECT_EQ(*out, "frame");
}

TEST(SpscRing, PopLatestSkipsToTheNewestAndCounts) {
  SpscRing<int> ring(8);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(ring.tryPush(i));
  int out = -1;
  size_t skipped = 0;
  ASSERT_TRUE(ring.popLatest(out, skipped));
  EXPECT_EQ(out, 4);
  EXPECT_EQ(skipped, 4u);
  EXPECT_FALSE(ring.popLatest(out, skipped));
  EXPECT_EQ(skipped, 0u);
}

// Two threads: every pushed value arrives once, in order, for a ring much
// smaller than the stream (wraps thousands of times). Run under
// ThreadSanitizer in CI.
TEST(SpscRing, TwoThreadsDeliverEveryValueInOrder) {
  constexpr uint64_t kCount = 200000;
  SpscRing<uint64_t> ring(64);
  uint64_t rejected = 0;
  std::thread producer([&] {
    for (uint64_t i = 1; i <= kCount; ++i) {
      while (!ring.tryPush(i)) {
        ++rejected;
        std::this_thread::yield();
      }
    }
  });
  uint64_t expected = 1, sum = 0;
  bool in_order = true;
  while (expected <= kCount) {
    uint64_t v = 0;
    if (!ring.tryPop(v)) {
      std::this_thread::yield();
      continue;
    }
    in_order &= v == expected;
    sum += v;
    ++expected;
  }
  producer.join();
  EXPECT_TRUE(in_order);
  EXPECT_EQ(sum, kCount * (kCount + 1) / 2);
  uint64_t extra = 0;
  EXPECT_FALSE(ring.tryPop(extra));
}

// The consumer skipping ahead while the producer keeps pushing: what it
// keeps plus what it skips is everything pushed, and values only increase.
TEST(SpscRing, TwoThreadsPopLatestAccountsForEveryValue) {
  constexpr uint64_t kCount = 100000;
  SpscRing<uint64_t> ring(16);
  std::thread producer([&] {
    for (uint64_t i = 1; i <= kCount; ++i) {
      while (!ring.tryPush(i)) std::this_thread::yield();
    }
  });
  uint64_t kept = 0, skipped_total = 0, last = 0;
  bool increasing = true;
  while (last < kCount) {
    uint64_t v = 0;
    size_t skipped = 0;
    if (!ring.popLatest(v, skipped)) {
      std::this_thread::yield();
      continue;
    }
    increasing &= v > last;
    EXPECT_EQ(v - last - 1, skipped) << "the skipped ones are exactly those between";
    last = v;
    ++kept;
    skipped_total += skipped;
  }
  producer.join();
  EXPECT_TRUE(increasing);
  EXPECT_EQ(kept + skipped_total, kCount);
}

TEST(LatestSlot, KeepsTheNewestAndReportsDrops) {
  LatestSlot<int> slot;
  int out = -1;
  EXPECT_FALSE(slot.take(out));
  EXPECT_FALSE(slot.publish(1));
  EXPECT_TRUE(slot.publish(2)) << "1 was never taken: dropped";
  EXPECT_TRUE(slot.publish(3));
  ASSERT_TRUE(slot.take(out));
  EXPECT_EQ(out, 3);
  EXPECT_FALSE(slot.take(out)) << "nothing new";
  EXPECT_FALSE(slot.publish(4));
  ASSERT_TRUE(slot.take(out));
  EXPECT_EQ(out, 4);
}

// Two threads: values taken only increase, and taken + dropped = published.
TEST(LatestSlot, TwoThreadsAccountForEveryValue) {
  constexpr int kCount = 100000;
  LatestSlot<std::unique_ptr<int>> slot;
  int dropped = 0;
  std::atomic<bool> done{false};
  std::thread producer([&] {
    for (int i = 1; i <= kCount; ++i) dropped += slot.publish(std::make_unique<int>(i)) ? 1 : 0;
    done = true;
  });
  int taken = 0, last = 0;
  bool increasing = true;
  std::unique_ptr<int> v;
  while (true) {
    if (slot.take(v)) {
      ASSERT_TRUE(v);
      increasing &= *v > last;
      last = *v;
      ++taken;
    } else if (done.load()) {
      if (!slot.take(v)) break;
      increasing &= *v > last;
      last = *v;
      ++taken;
    }
  }
  producer.join();
  EXPECT_TRUE(increasing);
  EXPECT_EQ(last, kCount) << "the last value published is taken";
  EXPECT_EQ(taken + dropped, kCount);
}

}  // namespace
}  // namespace hxmap::rt
