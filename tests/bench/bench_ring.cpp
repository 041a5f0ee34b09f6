// SPSC ring microbenchmark: throughput and round-trip latency between two
// threads pinned to different cores, against a mutex + std::deque baseline
// with the same try-push/try-pop interface. Prints numbers; asserts nothing.
//
//   bench_ring [items (default 10'000'000)] [round_trips (default 200'000)]
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include "hxmap/ring/spsc_ring.hpp"

using Clock = std::chrono::steady_clock;

namespace {

void pinTo(int cpu) {
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(cpu % static_cast<int>(std::max(1u, std::thread::hardware_concurrency())), &set);
  if (pthread_setaffinity_np(pthread_self(), sizeof(set), &set) != 0) std::fprintf(stderr, "warning: could not pin to CPU %d\n", cpu);
}

// The baseline: a bounded deque under a mutex, same interface.
template <typename T>
class MutexDeque {
 public:
  explicit MutexDeque(size_t capacity) : capacity_(capacity) {}
  [[nodiscard]] bool tryPush(const T& v) {
    std::lock_guard<std::mutex> lock(m_);
    if (q_.size() >= capacity_) return false;
    q_.push_back(v);
    return true;
  }
  [[nodiscard]] bool tryPop(T& out) {
    std::lock_guard<std::mutex> lock(m_);
    if (q_.empty()) return false;
    out = q_.front();
    q_.pop_front();
    return true;
  }

 private:
  size_t capacity_;
  std::mutex m_;
  std::deque<T> q_;
};

template <typename Queue>
double throughput(uint64_t items) {
  Queue q(1024);
  std::thread consumer([&] {
    pinTo(1);
    uint64_t v = 0, n = 0;
    while (n < items) {
      if (q.tryPop(v)) ++n;
    }
  });
  pinTo(0);
  const auto t0 = Clock::now();
  for (uint64_t i = 0; i < items; ++i) {
    while (!q.tryPush(i)) {
    }
  }
  consumer.join();
  const double s = std::chrono::duration<double>(Clock::now() - t0).count();
  return static_cast<double>(items) / s;
}

// Median and p99 of ping-pong round trips, in nanoseconds.
template <typename Queue>
std::pair<double, double> roundTrip(int trips) {
  Queue ping(64), pong(64);
  std::thread echo([&] {
    pinTo(1);
    uint64_t v = 0;
    for (int i = 0; i < trips; ++i) {
      while (!ping.tryPop(v)) {
      }
      while (!pong.tryPush(v)) {
      }
    }
  });
  pinTo(0);
  std::vector<double> ns(static_cast<size_t>(trips));
  uint64_t v = 0;
  for (int i = 0; i < trips; ++i) {
    const auto t0 = Clock::now();
    while (!ping.tryPush(static_cast<uint64_t>(i))) {
    }
    while (!pong.tryPop(v)) {
    }
    ns[static_cast<size_t>(i)] = std::chrono::duration<double, std::nano>(Clock::now() - t0).count();
  }
  echo.join();
  std::sort(ns.begin(), ns.end());
  return {ns[ns.size() / 2], ns[ns.size() * 99 / 100]};
}

}  // namespace

int main(int argc, char** argv) {
  const uint64_t items = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : 10'000'000ULL;
  const int trips = argc > 2 ? std::atoi(argv[2]) : 200'000;
  std::printf("threads pinned to CPUs 0 and 1 (%u online); %llu items, %d round trips\n",
              std::thread::hardware_concurrency(), static_cast<unsigned long long>(items), trips);
  const double r_tp = throughput<hxmap::rt::SpscRing<uint64_t>>(items);
  const double m_tp = throughput<MutexDeque<uint64_t>>(items);
  const auto r_rt = roundTrip<hxmap::rt::SpscRing<uint64_t>>(trips);
  const auto m_rt = roundTrip<MutexDeque<uint64_t>>(trips);
  std::printf("%-22s %14s %18s %14s\n", "", "throughput", "round trip p50", "p99");
  std::printf("%-22s %10.1f M/s %15.0f ns %11.0f ns\n", "SpscRing", r_tp / 1e6, r_rt.first, r_rt.second);
  std::printf("%-22s %10.1f M/s %15.0f ns %11.0f ns\n", "mutex + std::deque", m_tp / 1e6, m_rt.first, m_rt.second);
  std::printf("ring vs baseline: %.1fx throughput, %.1fx lower p50 round trip\n", r_tp / m_tp, m_rt.first / r_rt.first);
  return 0;
}
