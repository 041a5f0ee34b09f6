#include "hxmap/scheduler/replay.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "hxmap/core/stamp.hpp"
#include "hxmap/ring/latest_slot.hpp"

namespace hxmap::rt {

ReplayResult replay(const std::vector<ReplayFrame>& frames, const std::vector<ReplayJob>& jobs,
                    const SchedulerParams& params) {
  ReplayResult result;
  Scheduler sched(params);
  LatestSlot<size_t> sensor;
  struct Pending {
    ReplayJob job;
    JobTicket ticket;
    int done = 0;
    bool submitted = false;
  };
  std::vector<Pending> pending;
  for (const auto& j : jobs) pending.push_back({j, JobTicket{j.kind, j.estimate_ms}, 0, false});

  int64_t t = 0;
  size_t next_frame = 0;
  size_t newest_arrived = std::numeric_limits<size_t>::max();
  const int64_t period = sched.periodNs();
  auto deliver = [&]() {  // sensor: every frame that has arrived by t
    while (next_frame < frames.size() && frames[next_frame].arrival_ns <= t) {
      sched.frameArrived(frames[next_frame].arrival_ns);
      newest_arrived = next_frame;
      if (sensor.publish(size_t{next_frame})) sched.framesDropped(1);  // an unread older frame replaced
      ++next_frame;
    }
    for (auto& p : pending) {
      if (!p.submitted && p.job.submit_ns <= t) {
        sched.jobSubmitted(p.ticket, p.job.submit_ns);
        p.submitted = true;
      }
    }
  };
  auto nextEvent = [&]() {
    int64_t e = std::numeric_limits<int64_t>::max();
    if (next_frame < frames.size()) e = frames[next_frame].arrival_ns;
    for (const auto& p : pending) {
      if (!p.submitted) e = std::min(e, p.job.submit_ns);
    }
    return e;
  };

  result.worst_lateness_ms = -std::numeric_limits<double>::infinity();
  for (int guard = 0; guard < 100'000'000; ++guard) {
    deliver();
    // Frontend first: the newest frame, skipping stale ones.
    size_t idx = 0;
    if (sensor.take(idx)) {
      result.processed.push_back(idx);
      result.newest_at_start.push_back(newest_arrived);
      const ReplayFrame& f = frames[idx];
      sched.frameStarted(t, f.arrival_ns);
      t += msToNs(f.totalMs());
      sched.frameFinished(t, f.stage_ms);
      result.worst_lateness_ms =
          std::max(result.worst_lateness_ms, static_cast<double>(t - (f.arrival_ns + period)) * 1e-6);
      continue;
    }
    // CPU free: background work, first submitted first.
    bool ran = false, any_left = false;
    for (auto& p : pending) {
      if (!p.submitted || p.done >= p.job.slices || p.done < 0) continue;
      any_left = true;
      const Verdict v = sched.admitSlice(p.ticket, t);
      if (v == Verdict::kShed) {
        p.done = -1;
        continue;
      }
      if (v == Verdict::kWait) break;  // nothing else fits either (jobs run in order)
      const double ms = p.done == p.job.slow_slice ? p.job.slow_slice_ms : p.job.slice_ms;
      t += msToNs(ms);
      sched.sliceFinished(p.ticket, ms);
      if (++p.done == p.job.slices) sched.jobFinished(p.ticket);
      ran = true;
      break;
    }
    if (ran) continue;
    const int64_t e = nextEvent();
    if (e == std::numeric_limits<int64_t>::max()) {
      if (!any_left) break;
      t += period;  // only waiting jobs: time passes until they run or are shed
    } else {
      t = std::max(t + 1, e);
    }
  }
  result.counters = sched.counters();
  result.end_ns = t;
  result.report = sched.report();
  if (result.processed.empty()) result.worst_lateness_ms = 0;
  return result;
}

std::vector<ReplayFrame> steadyFrames(size_t count, double fps, const std::array<double, 4>& stage_ms) {
  std::vector<ReplayFrame> frames(count);
  for (size_t i = 0; i < count; ++i) {
    frames[i].arrival_ns = static_cast<int64_t>(std::llround(static_cast<double>(i) * 1e9 / fps));
    frames[i].stage_ms = stage_ms;
  }
  return frames;
}

}  // namespace hxmap::rt
