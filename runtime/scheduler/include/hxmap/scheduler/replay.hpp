// Deterministic replay of the runtime's scheduling on a virtual clock: frame
// arrivals and per-frame stage costs (from a recorded trace or constructed),
// background jobs made of slices, one shared CPU. The sensor publishes into
// a real LatestSlot (an unread older frame is dropped and counted), the
// frontend takes the newest, and the real Scheduler decides every background
// slice. Nothing sleeps, so tests assert exact outcomes.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "hxmap/scheduler/scheduler.hpp"

namespace hxmap::rt {

struct ReplayFrame {
  int64_t arrival_ns = 0;
  std::array<double, 4> stage_ms{};  ///< preprocess, track, integrate, raycast
  double totalMs() const { return stage_ms[0] + stage_ms[1] + stage_ms[2] + stage_ms[3]; }
};

struct ReplayJob {
  std::string kind = "refine";
  int64_t submit_ns = 0;
  double slice_ms = 5;     ///< what a slice really costs
  double estimate_ms = 5;  ///< what the job declares before it has run
  int slices = 1;
  int slow_slice = -1;  ///< this slice (index) really costs slow_slice_ms (preempted, say)
  double slow_slice_ms = 0;
};

struct ReplayResult {
  SchedulerCounters counters;
  std::vector<size_t> processed;        ///< frame indices in processing order
  std::vector<size_t> newest_at_start;  ///< newest arrived frame when each started
  double worst_lateness_ms = 0;         ///< max(finish - deadline), <= 0 when all met
  int64_t end_ns = 0;
  std::string report;
};

ReplayResult replay(const std::vector<ReplayFrame>& frames, const std::vector<ReplayJob>& jobs,
                    const SchedulerParams& params);

/// Frames at a fixed rate with constant stage costs (a constructed trace).
std::vector<ReplayFrame> steadyFrames(size_t count, double fps, const std::array<double, 4>& stage_ms);

}  // namespace hxmap::rt
