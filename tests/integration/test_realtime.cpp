// The real-time runner's threads on a short synthetic sequence. Timing
// varies with the machine (and ThreadSanitizer slows everything), so the
// assertions are accounting invariants and decisions that do not depend on
// timing, never "no deadline missed".
#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/runtime/realtime.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::rt {
namespace {

class RealtimeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto scene = drv::SyntheticScene::room();
    drv::SyntheticParams sp;
    sp.frames = 24;
    const auto traj = drv::syntheticTrajectory(sp);
    for (size_t i = 0; i < traj.size(); ++i) {
      RgbdFrame f = test::syntheticFrame(scene, cam_, traj[i].T_world_cam, false, static_cast<int>(i));
      f.stamp_ns = static_cast<int64_t>(i) * 50'000'000;  // recorded at 20 FPS
      frames_.push_back(std::move(f));
    }
    T0_ = traj.front().T_world_cam;
    fe_.setInitialPose(T0_);
    options_.status_interval_s = 0;
  }
  const alg::PinholeCamera cam_{160, 160, 79.5, 59.5, 160, 120, {0, 0, 0, 0, 0}};
  std::vector<RgbdFrame> frames_;
  Eigen::Isometry3d T0_;
  Frontend fe_{cam_, FrontendParams{}};
  RealtimeOptions options_;  // no status line
  std::atomic<bool> stop_{false};
};

TEST_F(RealtimeTest, EveryFrameIsProcessedOrCountedAsDropped) {
  TraceRecorder trace;
  const RealtimeStats s = runRealtime(frames_, fe_, options_, stop_, &trace);
  EXPECT_FALSE(s.stopped_early);
  EXPECT_EQ(s.counters.frames_in, frames_.size());
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in) << s.report;
  EXPECT_EQ(s.results.size(), s.counters.frames_processed);
  EXPECT_EQ(fe_.trajectory().size(), s.counters.frames_processed) << "no pose lost";
  EXPECT_GT(s.counters.frames_processed, 0u);
  EXPECT_GT(trace.size(), 0u);
  // Stamps of the processed frames only increase: the frontend never goes back.
  for (size_t i = 1; i < s.results.size(); ++i) EXPECT_GT(s.results[i].stamp_ns, s.results[i - 1].stamp_ns);
}

TEST_F(RealtimeTest, ABurningJobLargerThanAnyPeriodNeverRuns) {
  options_.burn_slice_ms = 200;  // four 50 ms periods: never fits
  options_.refine_workers = 2;
  const RealtimeStats s = runRealtime(frames_, fe_, options_, stop_);
  EXPECT_EQ(s.burn_slices_run, 0u) << s.report;
  EXPECT_EQ(s.counters.slices_admitted, 0u);
  EXPECT_GT(s.counters.jobs_submitted, 0u);
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in);
}

TEST_F(RealtimeTest, RefinementJobsAreWrittenBackOrCounted) {
  FrontendParams p;
  // Small jobs (this checks the plumbing, not the field) with ample slack
  // and no shedding, so that jobs complete even under ThreadSanitizer
  // (frontend frames up to 180 ms there).
  p.implicit.iterations = 6;
  p.implicit.rays_per_iteration = 48;
  p.implicit.max_rays = 3000;
  p.implicit.bias_rays = 150;
  Frontend fe(cam_, p);
  fe.setInitialPose(T0_);
  options_.fps = 3;  // 333 ms periods
  options_.scheduler.shed_after_periods = 1000;
  options_.refine_workers = 2;
  const RealtimeStats s = runRealtime(frames_, fe, options_, stop_);
  ASSERT_GT(fe.refineJobsMade(), 0u) << "the room's keyframes choose ROIs";
  EXPECT_EQ(s.refine_jobs_submitted + s.refine_jobs_rejected + fe.refineJobsDropped(), fe.refineJobsMade()) << s.report;
  EXPECT_LE(s.refine_jobs_completed + s.refine_jobs_shed, s.refine_jobs_submitted);
  EXPECT_GT(s.refine_jobs_completed, 0u) << s.report;
  EXPECT_EQ(s.refine_outcomes_dropped, 0u);
  EXPECT_GT(s.refine_voxels_written, 0u) << "completed jobs reach the map";
  EXPECT_LE(s.patches_applied, s.refine_jobs_completed);
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in);
}

TEST_F(RealtimeTest, FrontendAppliesPoseCorrectionsToItsTrajectory) {
  for (int i = 0; i < 3; ++i) fe_.process(frames_[static_cast<size_t>(i)]);
  PoseCorrection c{frames_[1].stamp_ns, Eigen::Isometry3d::Identity()};
  c.T_world_cam.translation() = Eigen::Vector3d(1, 2, 3);
  EXPECT_TRUE(fe_.applyPoseCorrection(c));
  EXPECT_TRUE(fe_.trajectory()[1].T_world_cam.translation().isApprox(Eigen::Vector3d(1, 2, 3)));
  EXPECT_FALSE(fe_.applyPoseCorrection({12345, Eigen::Isometry3d::Identity()})) << "no frame with that stamp";
  EXPECT_EQ(fe_.trajectory().size(), 3u);
}

TEST_F(RealtimeTest, StopEndsTheRunWithConsistentOutputs) {
  options_.fps = 5;  // 24 frames would take 4.8 s
  std::thread stopper([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(700));
    stop_ = true;  // as SIGINT/SIGTERM do
  });
  const RealtimeStats s = runRealtime(frames_, fe_, options_, stop_);
  stopper.join();
  EXPECT_TRUE(s.stopped_early);
  EXPECT_LT(s.counters.frames_in, frames_.size());
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in);
  EXPECT_EQ(fe_.trajectory().size(), s.counters.frames_processed);
}

}  // namespace
}  // namespace hxmap::rt
