#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <thread>
#include <vector>

#include "hxmap/scheduler/replay.hpp"
#include "hxmap/scheduler/scheduler.hpp"
#include "hxmap/scheduler/trace.hpp"

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

TEST(SchedulerReplay, OneSlowSliceDoesNotCostAStartedJobItsWork) {
  // 19 ms of frontend per 40 ms period (20 ms of slack after the margin);
  // slices of 7 ms, one of which is preempted and takes 21 ms. The recent
  // maximum then keeps the next slices waiting until it ages out
  // (recent_frames periods), longer than an unstarted job may wait: the
  // started job waits, and completes.
  const auto frames = steadyFrames(300, 25.0, {4, 8, 2, 5});
  std::vector<ReplayJob> jobs{{"refine", 0, 7.0, 7.0, 60, 1, 21.0}};
  SchedulerParams p;
  const ReplayResult r = replay(frames, jobs, p);
  EXPECT_EQ(r.counters.deadline_misses, 0u) << r.report;
  EXPECT_GT(r.counters.slices_paused, 0u) << "the slow slice held the next ones back";
  EXPECT_EQ(r.counters.jobs_cancelled, 0u) << r.report;
  EXPECT_EQ(r.counters.jobs_completed, 1u) << r.report;
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

TEST(Scheduler, OneSlowSliceDoesNotStarveItsKindForever) {
  // Frames of 20 ms at 25 FPS leave about 19 ms of slack. A refine slice
  // that once took 30 ms (preempted) holds the kind back for the recent
  // horizon (recent_frames periods), then the EWMA plans again.
  SchedulerParams p;
  p.recent_frames = 8;
  p.shed_after_periods = 1000;  // waiting, not shedding, is under test
  Scheduler s(p);
  const int64_t ms = 1'000'000, period = s.periodNs();
  JobTicket job{"refine", 3.0};
  s.jobSubmitted(job, 0);
  int64_t t = 0;
  auto frame = [&] {
    s.frameArrived(t);
    s.frameStarted(t, t);
    s.frameFinished(t + 20 * ms, {5, 10, 2, 3});
  };
  for (int i = 0; i < 4; ++i, t += period) frame();
  // Between frames: admitted, and slices of 3 ms are measured.
  for (int i = 0; i < 5; ++i, t += period) {
    frame();
    ASSERT_EQ(s.admitSlice(job, t + 21 * ms), Verdict::kRun) << i;
    s.sliceFinished(job, 3.0);
  }
  frame();
  ASSERT_EQ(s.admitSlice(job, t + 21 * ms), Verdict::kRun);
  s.sliceFinished(job, 30.0);  // the slow one
  t += period;
  int waited = 0, first_run = -1;
  for (int i = 0; i < 3 * p.recent_frames && first_run < 0; ++i, t += period) {
    frame();
    if (s.admitSlice(job, t + 21 * ms) == Verdict::kRun) {
      first_run = i;
    } else {
      ++waited;
    }
  }
  EXPECT_GT(waited, 0) << "right after the slow slice the kind waits";
  ASSERT_GE(first_run, 0) << "starved: never admitted again";
  EXPECT_LE(first_run, p.recent_frames + 1);
}

// 30 FPS, frames of 11 ms: admitted 12 ms after a frame's arrival, a slice
// has about 20 ms of slack. The first slice of kind "setup" measures 35 ms.
// Returns the periods after it until the kind's next admission (-1: none
// within `periods`), and the admissions in all.
struct SetupProbe {
  int first_after = -1;
  int admitted = 0;
};
SetupProbe runAfterASlowFirstSlice(const SchedulerParams& p, double every_slice_ms, int periods) {
  Scheduler s(p);
  const int64_t ms = 1'000'000, period = s.periodNs();
  int64_t t = 0;
  auto frame = [&] {
    s.frameArrived(t);
    s.frameStarted(t, t);
    s.frameFinished(t + 11 * ms, {2, 5, 2, 2});
  };
  for (int i = 0; i < 4; ++i, t += period) frame();
  JobTicket job{"setup", 10.0};  // what the job declares: 10 ms
  s.jobSubmitted(job, t);
  frame();
  EXPECT_EQ(s.admitSlice(job, t + 12 * ms), Verdict::kRun);
  s.sliceFinished(job, 35.0);
  t += period;
  SetupProbe out;
  out.admitted = 1;
  for (int i = 0; i < periods; ++i, t += period) {
    frame();
    JobTicket next{"setup", 10.0};
    s.jobSubmitted(next, t);
    if (s.admitSlice(next, t + 12 * ms) == Verdict::kRun) {
      s.sliceFinished(next, every_slice_ms);
      ++out.admitted;
      if (out.first_after < 0) out.first_after = i;
    }
  }
  EXPECT_EQ(s.counters().deadline_misses, 0u);
  return out;
}

TEST(Scheduler, AKindWhoseFirstSliceWasAnOutlierRunsAgain) {
  // The first ROI job's setup in a fresh process: 35 ms, where later ones
  // take 3. Without a fresher sample the kind's EWMA stays at 35 ms, above
  // any slack at 30 FPS, and no later job of the kind would ever start.
  SchedulerParams p;
  p.target_fps = 30;
  const SetupProbe r = runAfterASlowFirstSlice(p, 3.0, 10 * p.recent_frames);
  ASSERT_GE(r.first_after, 0) << "starved: never admitted again";
  EXPECT_GE(r.first_after, p.recent_frames) << "held back while the slow slice is recent";
  // The gap to the declared 10 ms halves every horizon: 10 + 25 / 2^h fits
  // 20.3 ms of slack after h = 1.3 horizons of staleness.
  EXPECT_LE(r.first_after, 3 * p.recent_frames);
  EXPECT_GT(r.admitted, 5 * p.recent_frames) << "then every period's job starts";
}

TEST(Scheduler, AKindThatReallyCostsMoreThanTheSlackIsTriedAgainOnlyTwice) {
  SchedulerParams p;
  p.target_fps = 30;
  const SetupProbe r = runAfterASlowFirstSlice(p, 35.0, 40 * p.recent_frames);
  EXPECT_GE(r.first_after, p.recent_frames);
  // Three slices of 35 ms outvote the declared 10 ms: the kind's median.
  EXPECT_EQ(r.admitted, 3);
}

TEST(Scheduler, NoMoreSlicesRunAtOnceThanThereAreLanes) {
  // Plenty of slack: what limits three background threads is the two
  // cores the slack is on.
  SchedulerParams p;
  p.background_lanes = 2;
  Scheduler s(p);
  const int64_t ms = 1'000'000;
  for (int i = 0; i < 3; ++i) {
    s.frameArrived(i * 40 * ms);
    s.frameStarted(i * 40 * ms, i * 40 * ms);
    s.frameFinished(i * 40 * ms + 5 * ms, {1, 2, 1, 1});
  }
  const int64_t t = 86 * ms;  // 33 ms of slack
  JobTicket a{"refine", 3.0}, b{"refine", 3.0}, c{"loop", 3.0};
  for (JobTicket* j : {&a, &b, &c}) s.jobSubmitted(*j, t);
  EXPECT_EQ(s.admitSlice(a, t), Verdict::kRun);
  EXPECT_EQ(s.admitSlice(b, t), Verdict::kRun);
  EXPECT_EQ(s.runningSlices(), 2);
  EXPECT_EQ(s.admitSlice(c, t), Verdict::kWait) << "both lanes are taken";
  s.sliceFinished(a, 3.0);
  EXPECT_EQ(s.runningSlices(), 1);
  EXPECT_EQ(s.admitSlice(c, t + 3 * ms), Verdict::kRun) << "a lane is free again";
  // A slice run without admission (one that could not be given up) is
  // measured, and frees no lane it never held.
  JobTicket forced{"loop", 3.0};
  s.sliceFinished(forced, 4.0);
  EXPECT_EQ(s.runningSlices(), 2);
  s.sliceFinished(b, 3.0);
  s.sliceFinished(c, 3.0);
  EXPECT_EQ(s.runningSlices(), 0);
  EXPECT_EQ(Scheduler().backgroundLanes(), std::max(1, static_cast<int>(std::thread::hardware_concurrency())));
}

TEST(Scheduler, AFrameWaitingToStartTakesItsPredictedCostFromTheSlack) {
  Scheduler s;  // 25 FPS, 1 ms margin, 3 warm-up frames
  JobTicket job{"refine", 20.0};
  s.jobSubmitted(job, 0);
  const int64_t ms = 1'000'000;
  for (int i = 0; i < 3; ++i) {  // frames of 30 ms at 0, 40, 80 ms
    EXPECT_EQ(s.admitSlice(job, i * 40 * ms), Verdict::kWait) << "no slice before the warm-up frames";
    s.frameArrived(i * 40 * ms);
    s.frameStarted(i * 40 * ms, i * 40 * ms);
    s.frameFinished(i * 40 * ms + 30 * ms, {5, 10, 5, 10});
  }
  EXPECT_NEAR(s.slackMs(111 * ms), 120 - 1 - 111, 1e-6) << "the next frame is due at 120 ms";
  s.frameArrived(120 * ms);
  // At 121 ms the frame that arrived at 120 ms still waits: it will run to
  // ~151 ms, and the next is due at 160 ms.
  EXPECT_NEAR(s.slackMs(121 * ms), 160 - 1 - (121 + 30), 1e-6);
  EXPECT_EQ(s.admitSlice(job, 121 * ms), Verdict::kWait);
  s.frameStarted(121 * ms, 120 * ms);
  s.frameFinished(151 * ms, {5, 10, 5, 10});
  EXPECT_NEAR(s.slackMs(151 * ms), 8.0, 1e-6);
  JobTicket small{"small", 5.0};
  s.jobSubmitted(small, 151 * ms);
  EXPECT_EQ(s.admitSlice(small, 151 * ms), Verdict::kRun);
}

// A trace recorded from `hxmap run --trace` on the shared TUM fr1/xyz slice
// (both cores; frontend median 23 ms), replayed at its recorded 30 FPS.
std::vector<ReplayFrame> recordedTumFrames() {
  auto events = readTrace(std::string(HXMAP_SOURCE_DIR) + "/tests/replay/tum_fr1_xyz_first40.json");
  EXPECT_TRUE(events) << events.message();
  if (!events) return {};
  auto frames = replayFramesFromTrace(*events);
  EXPECT_TRUE(frames) << frames.message();
  return frames ? *frames : std::vector<ReplayFrame>{};
}

TEST(SchedulerReplay, RecordedTumTraceWithABurningJobHasNoMissAndShedsIt) {
  const auto frames = recordedTumFrames();
  ASSERT_EQ(frames.size(), 35u);
  double worst = 0;
  for (const auto& f : frames) worst = std::max(worst, f.totalMs());
  ASSERT_LT(worst, 33.0) << "the recorded frontend fits the 30 FPS period by itself";
  SchedulerParams p;
  p.target_fps = 30;
  // A CPU-burning refinement job: 30 ms slices, about three times the slack.
  std::vector<ReplayJob> jobs{{"refine", 0, 30.0, 30.0, 100}};
  const ReplayResult r = replay(frames, jobs, p);
  EXPECT_EQ(r.counters.deadline_misses, 0u) << r.report;
  EXPECT_EQ(r.counters.frames_processed, 35u);
  EXPECT_EQ(r.counters.slices_admitted, 0u);
  EXPECT_EQ(r.counters.jobs_shed_unstarted, 1u) << r.report;
}

TEST(SchedulerReplay, RecordedTumTraceWithLightJobsCompletesThem) {
  const auto frames = recordedTumFrames();
  SchedulerParams p;
  p.target_fps = 30;
  std::vector<ReplayJob> jobs;
  for (int i = 0; i < 8; ++i) jobs.push_back({"refine", i * 100'000'000LL, 2.0, 2.0, 3});
  const ReplayResult r = replay(frames, jobs, p);
  EXPECT_EQ(r.counters.deadline_misses, 0u) << r.report;
  EXPECT_EQ(r.counters.jobs_completed, 8u) << r.report;
}

TEST(Trace, WritesAndReadsBackChromeJson) {
  TraceRecorder rec;
  rec.nameThread(1, "frontend");
  for (int f = 0; f < 3; ++f) {
    const int64_t t0 = f * 40'000'000LL;
    rec.add({"preprocess", "frontend", t0, 5'000'000, 1, f, 1000 + f * 33'000'000LL});
    rec.add({"track", "frontend", t0 + 5'000'000, 8'000'500, 1, f, 1000 + f * 33'000'000LL});
  }
  const auto events = parseTrace(rec.toJson(), "memory");
  ASSERT_TRUE(events) << events.message();
  ASSERT_EQ(events->size(), 6u);
  EXPECT_EQ((*events)[1].name, "track");
  EXPECT_EQ((*events)[1].duration_ns, 8'000'500);
  const auto frames = replayFramesFromTrace(*events);
  ASSERT_TRUE(frames) << frames.message();
  ASSERT_EQ(frames->size(), 3u);
  EXPECT_EQ((*frames)[2].arrival_ns, 66'000'000);
  EXPECT_NEAR((*frames)[2].totalMs(), 13.0005, 1e-9);
}

TEST(Trace, BadTracesGiveErrorsNamingTheSource) {
  auto a = parseTrace("{\"traceEvents\": [", "broken.json");
  ASSERT_FALSE(a);
  EXPECT_NE(a.message().find("broken.json"), std::string::npos) << a.message();
  auto b = parseTrace("{\"other\": 1}", "other.json");
  ASSERT_FALSE(b);
  EXPECT_NE(b.message().find("traceEvents"), std::string::npos) << b.message();
  auto c = parseTrace("{\"traceEvents\": [{\"ph\": \"X\", \"name\": \"track\"}]}", "nots.json");
  ASSERT_FALSE(c);
  EXPECT_NE(c.message().find("nots.json: event 0"), std::string::npos) << c.message();
  EXPECT_FALSE(readTrace("/nonexistent/trace.json"));
  EXPECT_FALSE(replayFramesFromTrace({}));
}

}  // namespace
}  // namespace hxmap::rt
