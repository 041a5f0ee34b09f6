#include <gtest/gtest.h>

#include "hxmap/runtime/replay.hpp"
#include "hxmap/runtime/scheduler.hpp"

namespace hxmap::rt {
namespace {

// 25 FPS: 40 ms per frame. The frontend takes 30 ms, so with the 1 ms margin
// each period leaves 9 ms of slack.
const std::array<double, 4> kFrontend30{6, 12, 2, 10};

TEST(CostModel, EwmaRecentMaxAndPercentiles) {
  CostModel m(0.5, 4);
  for (double x : {10.0, 10.0, 30.0, 10.0}) m.add(x);
  EXPECT_NEAR(m.ewma(), 0.5 * 10 + 0.5 * (0.5 * 30 + 0.5 * 10), 1e-9);
  EXPECT_DOUBLE_EQ(m.recentMax(), 30.0);
  EXPECT_DOUBLE_EQ(m.predict(), 30.0) << "plans with the larger of EWMA and the recent maximum";
  for (int i = 0; i < 4; ++i) m.add(12.0);  // the 30 ms spike leaves the window
  EXPECT_DOUBLE_EQ(m.recentMax(), 12.0);
  EXPECT_DOUBLE_EQ(m.percentile(0.5), 12.0);
}

TEST(SchedulerReplay, RefinementAtThreeTimesTheSlackIsShedWithNoMiss) {
  const auto frames = steadyFrames(200, 25.0, kFrontend30);
  std::vector<ReplayJob> jobs;
  for (int i = 0; i < 10; ++i) jobs.push_back({"refine", i * 40'000'000LL, 27.0, 27.0, 4});
  SchedulerParams p;
  const ReplayResult r = replay(frames, jobs, p);
  EXPECT_EQ(r.counters.deadline_misses, 0u) << r.report;
  EXPECT_LE(r.worst_lateness_ms, 0.0);
  EXPECT_EQ(r.counters.frames_processed, 200u);
  EXPECT_EQ(r.counters.slices_admitted, 0u) << "27 ms never fits into 9 ms of slack";
  EXPECT_EQ(r.counters.jobs_completed, 0u);
  EXPECT_EQ(r.counters.jobs_shed_unstarted, 10u) << r.report;
}

TEST(SchedulerReplay, LightLoadCompletesEveryJob) {
  const auto frames = steadyFrames(200, 25.0, {3, 6, 1, 5});  // 15 ms of 40
  std::vector<ReplayJob> jobs;
  for (int i = 0; i < 20; ++i) jobs.push_back({"refine", i * 100'000'000LL, 5.0, 5.0, 6});
  const ReplayResult r = replay(frames, jobs, SchedulerParams{});
  EXPECT_EQ(r.counters.deadline_misses, 0u) << r.report;
  EXPECT_EQ(r.counters.jobs_completed, 20u) << r.report;
  EXPECT_EQ(r.counters.slices_admitted, 120u);
  EXPECT_EQ(r.counters.jobs_shed_unstarted + r.counters.jobs_cancelled, 0u);
}

TEST(SchedulerReplay, JobsThatOutgrowTheSlackArePausedThenCancelled) {
  // Slices fit at first (15 ms frontend), then the frontend slows to 35 ms
  // per frame (4 ms of slack): a started job is paused, then cancelled.
  auto frames = steadyFrames(300, 25.0, {3, 6, 1, 5});
  for (size_t i = 20; i < frames.size(); ++i) frames[i].stage_ms = {7, 14, 2, 12};
  std::vector<ReplayJob> jobs{{"refine", 0, 8.0, 8.0, 1000}};
  const ReplayResult r = replay(frames, jobs, SchedulerParams{});
  EXPECT_EQ(r.counters.deadline_misses, 0u) << r.report;
  EXPECT_GT(r.counters.slices_admitted, 0u);
  EXPECT_GT(r.counters.slices_paused, 0u);
  EXPECT_EQ(r.counters.jobs_cancelled, 1u) << r.report;
}

TEST(SchedulerReplay, SensorBurstsAreDroppedAndTheNewestFrameIsNext) {
  // Bursts of 6 frames 1 ms apart every 200 ms, 10 ms of frontend each.
  std::vector<ReplayFrame> frames;
  for (int b = 0; b < 20; ++b) {
    for (int k = 0; k < 6; ++k) {
      ReplayFrame f;
      f.arrival_ns = b * 200'000'000LL + k * 1'000'000LL;
      f.stage_ms = {2, 4, 1, 3};  // 10 ms
      frames.push_back(f);
    }
  }
  const ReplayResult r = replay(frames, {}, SchedulerParams{});
  EXPECT_EQ(r.counters.frames_in, frames.size());
  EXPECT_EQ(r.counters.frames_dropped, r.counters.frames_in - r.counters.frames_processed) << r.report;
  EXPECT_GT(r.counters.frames_dropped, 0u);
  ASSERT_EQ(r.processed.size(), r.newest_at_start.size());
  for (size_t i = 0; i < r.processed.size(); ++i) {
    EXPECT_EQ(r.processed[i], r.newest_at_start[i]) << "frame " << i << " was not the newest";
  }
  EXPECT_EQ(r.counters.deadline_misses, 0u);
}

TEST(Scheduler, FeedbackEffortDropsUnderTightSlackAndRecovers) {
  SchedulerParams p;
  Scheduler s(p);
  JobTicket fb{"feedback", 12.0};
  s.jobSubmitted(fb, 0);
  s.sliceFinished(fb, 12.0);  // full effort costs 12 ms
  EXPECT_EQ(s.feedbackEffort(), 3);
  int64_t t = 0;
  const int64_t period = s.periodNs();
  // Frames of 36 ms: 3 ms of slack, less than one level (4 ms).
  for (int i = 0; i < 5; ++i, t += period) {
    s.frameArrived(t);
    s.frameStarted(t, t);
    s.frameFinished(t + 36'000'000, {8, 14, 2, 12});
  }
  EXPECT_EQ(s.feedbackEffort(), 0);
  // Frames of 10 ms: 29 ms of slack holds full effort again.
  for (int i = 0; i < 5; ++i, t += period) {
    s.frameArrived(t);
    s.frameStarted(t, t);
    s.frameFinished(t + 10'000'000, {2, 4, 1, 3});
  }
  EXPECT_EQ(s.feedbackEffort(), 3);
}

}  // namespace
}  // namespace hxmap::rt
