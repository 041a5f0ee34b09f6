#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <future>
#include <thread>

#include "hxmap/ring/doorbell.hpp"

namespace hxmap::rt {
namespace {

using namespace std::chrono_literals;

// Runs `body` on a thread and reports whether it returned within `limit`.
// A thread still blocked then is released by `release` and joined, so a
// failing test fails instead of hanging.
template <typename Body, typename Release>
bool returnsWithin(std::chrono::milliseconds limit, Body body, Release release) {
  std::promise<void> finished;
  std::future<void> end = finished.get_future();
  std::thread t([&] {
    body();
    finished.set_value();
  });
  const bool in_time = end.wait_for(limit) == std::future_status::ready;
  while (end.wait_for(1ms) != std::future_status::ready) release();
  t.join();
  return in_time;
}

TEST(Doorbell, AWaitWithTheStopAlreadySetReturnsAtOnce) {
  Doorbell bell;
  std::atomic<bool> stopping{false};
  const uint32_t seen = bell.read();
  bell.ring();  // the ring a stopping thread makes: the count moved on
  stopping.store(true);
  // The waiter read the count after that ring: only the flag can wake it.
  EXPECT_TRUE(returnsWithin(2000ms, [&] { bell.wait(bell.read(), stopping); }, [&] { bell.ring(); }));
  // A count read before the ring returns at once too, flag or not.
  stopping.store(false);
  EXPECT_TRUE(returnsWithin(2000ms, [&] { bell.wait(seen, stopping); }, [&] { bell.ring(); }));
}

TEST(Doorbell, AWaiterWakesForEveryRingAndEndsOnStop) {
  // A worker loop as the runtime's stages write it, stopped at every
  // possible moment: each of 2000 runs must end without a second ring.
  int hung = 0, runs = 0;
  for (int run = 0; run < 2000; ++run) {
    Doorbell bell;
    std::atomic<bool> stopping{false};
    std::atomic<int> work{0}, done{0};
    const int jobs = run % 4;
    const bool in_time = returnsWithin(
        2000ms,
        [&] {
          std::thread stopper([&] {
            for (int j = 0; j < jobs; ++j) {
              work.fetch_add(1);
              bell.ring();
            }
            // Stop only once every job is taken, so the count is exact.
            while (done.load() < jobs) std::this_thread::yield();
            stopping.store(true);
            bell.ring();
          });
          while (!stopping.load()) {
            const uint32_t seen = bell.read();
            if (work.load() > 0) {
              work.fetch_sub(1);
              done.fetch_add(1);
              continue;
            }
            bell.wait(seen, stopping);
          }
          stopper.join();
        },
        [&] { bell.ring(); });
    hung += !in_time;
    ++runs;
    EXPECT_EQ(done.load(), jobs);
  }
  EXPECT_EQ(hung, 0) << "of " << runs << " runs";
}

TEST(LatestInbox, TakesTheNewestAndEndsOnceClosedAndEmpty) {
  LatestInbox<int> inbox;
  EXPECT_FALSE(inbox.publish(1));
  EXPECT_TRUE(inbox.publish(2)) << "1 was not taken: replaced";
  inbox.close();
  int out = 0;
  ASSERT_TRUE(inbox.take(out)) << "a value published before the close is still taken";
  EXPECT_EQ(out, 2);
  EXPECT_FALSE(inbox.take(out));
  EXPECT_EQ(out, 2);
}

TEST(LatestInbox, TheLastValueBeforeTheCloseIsNeverLost) {
  // Values may be replaced on the way (newest only), but the last one
  // published before the close always arrives, wherever the consumer is.
  int lost = 0;
  for (int run = 0; run < 500; ++run) {
    LatestInbox<int> inbox;
    const int n = 1 + run % 7;
    std::thread producer([&] {
      for (int v = 1; v <= n; ++v) inbox.publish(int(v));
      inbox.close();
    });
    int last = 0, taken = 0, prev = 0;
    for (int v = 0; inbox.take(v);) {
      EXPECT_GT(v, prev) << "values arrive in order";
      prev = last = v;
      ++taken;
    }
    producer.join();
    lost += last != n;
    EXPECT_GE(taken, 1);
  }
  EXPECT_EQ(lost, 0) << "runs whose last value was lost";
}

}  // namespace
}  // namespace hxmap::rt
