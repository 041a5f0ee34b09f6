// A synthetic CPU load beside a real-time run (RealtimeOptions::extra_load):
// jobs of fixed slices under the run's scheduler, resubmitted as soon as one
// ends or is shed, to watch the scheduler shed work.
#pragma once

#include <atomic>
#include <cmath>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "hxmap/realtime/realtime.hpp"

namespace hxmap::test {

class BurnLoad : public rt::BackgroundLoad {
 public:
  BurnLoad(int threads, double slice_ms, int slices_per_job = 20)
      : threads_n_(threads), slice_ms_(slice_ms), slices_per_job_(slices_per_job) {}
  void start(rt::Scheduler& sched, std::function<int64_t()> now_ns, const std::atomic<bool>& stopping,
             rt::TraceRecorder* trace) override {
    for (int i = 0; i < threads_n_; ++i) {
      threads_.emplace_back([this, &sched, now_ns, &stopping, trace, i] { run(sched, now_ns, stopping, trace, i); });
    }
  }
  void join() override {
    for (auto& t : threads_) t.join();
    threads_.clear();
  }
  std::string reportLine() const override {
    return fmt::format("burn load: {} slices ({:.0f} ms of CPU)", slices(), static_cast<double>(slices()) * slice_ms_);
  }
  uint64_t slices() const { return slices_.load(); }

 private:
  void run(rt::Scheduler& sched, const std::function<int64_t()>& now_ns, const std::atomic<bool>& stopping,
           rt::TraceRecorder* trace, int lane) {
    rt::JobTicket job{"burn", slice_ms_};
    int done = 0;
    sched.jobSubmitted(job, now_ns());
    volatile double sink = 0;
    while (!stopping.load()) {
      if (done == slices_per_job_) {  // before asking: an admitted slice holds a lane until it finishes
        sched.jobFinished(job);
        job = rt::JobTicket{"burn", slice_ms_};
        done = 0;
        sched.jobSubmitted(job, now_ns());
      }
      const uint64_t epoch = sched.frameEpoch();
      const rt::Verdict v = sched.admitSlice(job, now_ns());
      if (v == rt::Verdict::kWait) {
        if (!stopping.load()) sched.waitForFrameEnd(epoch);  // slack changes when a frame ends
        continue;
      }
      if (v == rt::Verdict::kShed) {
        job = rt::JobTicket{"burn", slice_ms_};
        done = 0;
        sched.jobSubmitted(job, now_ns());
        continue;
      }
      const int64_t s0 = now_ns(), s_end = s0 + static_cast<int64_t>(slice_ms_ * 1e6);
      while (now_ns() < s_end) {  // burn the CPU
        for (int k = 0; k < 1000; ++k) sink = sink + std::sqrt(static_cast<double>(k) + sink * 1e-9);
      }
      const int64_t s1 = now_ns();
      sched.sliceFinished(job, static_cast<double>(s1 - s0) * 1e-6);
      slices_.fetch_add(1);
      ++done;
      if (trace) trace->add({"burn", "background", s0, s1 - s0, 10 + lane, -1, -1});
    }
    (void)sink;
  }

  int threads_n_;
  double slice_ms_;
  int slices_per_job_;
  std::atomic<uint64_t> slices_{0};
  std::vector<std::thread> threads_;
};

}  // namespace hxmap::test
