// The real-time runner's threads on a short synthetic sequence. Timing
// varies with the machine (and ThreadSanitizer slows everything), so the
// assertions are accounting invariants and decisions that do not depend on
// timing, never "no deadline missed".
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <map>
#include <mutex>
#include <thread>

#include "burn_load.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"

#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/realtime/realtime.hpp"
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
    // Background threads at the process's priority: CI runs other test
    // processes beside this one, and niced workers would starve behind
    // them (what the nice value is for on a robot, not what these tests
    // are about).
    options_.background_nice = 0;
  }
  const alg::PinholeCamera cam_{160, 160, 79.5, 59.5, 160, 120, {0, 0, 0, 0, 0}};
  std::vector<RgbdFrame> frames_;
  Eigen::Isometry3d T0_;
  static FrontendParams withFeedback() {
    FrontendParams p;
    p.feedback.enabled = true;  // off by default; these tests exercise its thread
    return p;
  }
  Frontend fe_{cam_, withFeedback()};
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

TEST_F(RealtimeTest, EveryKeyframeReachesTheLoopClosersThread) {
  // The loop closer runs on its own thread during the run and comes back
  // to the frontend after it; its pose graph must hold every keyframe
  // (a keyframe missing from the chain would break the odometry factors).
  ASSERT_NE(fe_.loopCloser(), nullptr) << "loop closure is on by default";
  const RealtimeStats s = runRealtime(frames_, fe_, options_, stop_);
  ASSERT_NE(fe_.loopCloser(), nullptr) << "attached again after the run";
  EXPECT_GT(fe_.keyframes(), 1u);
  EXPECT_EQ(fe_.loopCloser()->graph().nodes().size(), fe_.keyframes()) << s.report;
  EXPECT_EQ(fe_.loopCloser()->counters().keyframes, fe_.keyframes());
  EXPECT_EQ(fe_.loopCloser()->graph().factors().size() + 1, fe_.keyframes()) << "one odometry factor per keyframe after the first";
  EXPECT_TRUE(fe_.takeLoopKeyframes().empty());
  EXPECT_NE(s.report.find("loop closure:"), std::string::npos) << s.report;
}

// Each keyframe's database entry: at the keyframe's pose in `fe`'s
// trajectory, and with the descriptors the frontend makes itself (a run of
// process() alone: `reference`, by the keyframe's frame stamp). Returns how
// many keyframes were made at a frame the reference also made one at (a
// real-time run under load drops frames, and its keyframes fall elsewhere).
size_t expectDatabaseOfEveryKeyframe(const Frontend& fe, const std::vector<FrameResult>& results,
                                     const std::map<int64_t, cv::Mat>& reference, const std::string& report) {
  std::map<uint32_t, size_t> index;  // keyframe id -> trajectory entry
  for (size_t i = 0; i < results.size(); ++i) {
    if (results[i].keyframe) index[results[i].keyframe_id] = i;
  }
  const auto& kfs = fe.keyframeDatabase().keyframes();
  EXPECT_EQ(kfs.size(), fe.keyframes()) << report;
  EXPECT_EQ(kfs.size(), index.size());
  size_t compared = 0;
  for (size_t k = 0; k < kfs.size(); ++k) {
    SCOPED_TRACE("keyframe " + std::to_string(kfs[k].id));
    if (index.count(kfs[k].id) != 1) {
      ADD_FAILURE() << "no frame made it";
      continue;
    }
    const size_t i = index[kfs[k].id];
    const Eigen::Isometry3d& T = fe.trajectory()[i].T_world_cam;
    EXPECT_LT((kfs[k].T_world_cam.matrix() - T.matrix()).cwiseAbs().maxCoeff(), 1e-9) << "at its pose now";
    const auto r = reference.find(results[i].stamp_ns);
    if (r == reference.end()) continue;
    ++compared;
    EXPECT_EQ(kfs[k].descriptors.rows, r->second.rows);
    if (kfs[k].descriptors.size() == r->second.size()) {
      EXPECT_EQ(cv::norm(kfs[k].descriptors, r->second, cv::NORM_HAMMING), 0.0) << "the same image, the same features";
    }
  }
  return compared;
}

TEST_F(RealtimeTest, KeyframeFeaturesAreMadeOffTheFrontendThreadAndReachItsDatabase) {
  // Relocalization's keyframe database, filled from the loop closure
  // thread in real time (with loop closure on, and off: the thread then
  // only describes keyframes) and after each frame in a serial run.
  FrontendParams base;
  base.refine.enabled = false;  // not what this is about (a serial run would run every job)
  Frontend alone{cam_, base};
  alone.setInitialPose(T0_);
  std::map<uint32_t, int64_t> stamp_of;  // keyframe id -> its frame's stamp
  for (const RgbdFrame& f : frames_) {
    const FrameResult r = alone.process(f);
    if (r.keyframe) stamp_of[r.keyframe_id] = r.stamp_ns;
  }
  std::map<int64_t, cv::Mat> reference;
  for (const auto& e : alone.keyframeDatabase().keyframes()) reference[stamp_of.at(e.id)] = e.descriptors;
  ASSERT_GT(reference.size(), 1u);
  for (const bool loop : {true, false}) {
    for (const bool serial : {false, true}) {
      SCOPED_TRACE(std::string(loop ? "loop closure on" : "loop closure off") + (serial ? ", serial" : ", threads"));
      FrontendParams p = base;
      p.loop_closure.enabled = loop;
      Frontend fe{cam_, p};
      fe.setInitialPose(T0_);
      PlaybackSource source(frames_, 20.0);
      TraceRecorder trace;
      const RealtimeStats s =
          serial ? runSerial(source, fe, options_, stop_, &trace) : runRealtime(frames_, fe, options_, stop_, &trace);
      const size_t compared = expectDatabaseOfEveryKeyframe(fe, s.results, reference, s.report);
      // A serial run sees every frame: its keyframes are the reference's.
      if (serial) {
        EXPECT_EQ(compared, fe.keyframes());
      }
      // Made by the background stage, one event per keyframe, none on the
      // frontend's lane.
      const auto events = parseTrace(trace.toJson(), "trace");
      ASSERT_TRUE(events) << events.message();
      size_t described = 0;
      for (const TraceEvent& e : *events) described += e.name == "keyframe features" && e.category == "background";
      EXPECT_EQ(described, fe.keyframes());
      EXPECT_GT(fe.trackingCounters().keyframe_features_ms, 0.0);
      EXPECT_NE(s.report.find("keyframe features (ORB"), std::string::npos) << s.report;
      EXPECT_TRUE(fe.takeLoopKeyframes().empty()) << "nothing left behind";
    }
  }
}

TEST_F(RealtimeTest, FrameLimitEndsTheStreamAfterItsFrames) {
  PlaybackSource all(frames_, 1000.0);
  FrameLimit limited(all, 5);
  EXPECT_EQ(limited.size(), 5u);
  size_t n = 0;
  for (;;) {
    auto f = limited.next(stop_);
    ASSERT_TRUE(f) << f.message();
    if (!*f) break;
    EXPECT_EQ((*f)->stamp_ns, frames_[n].stamp_ns) << "the inner source's frames, in order";
    ++n;
  }
  EXPECT_EQ(n, 5u);
  EXPECT_FALSE(*limited.next(stop_)) << "stays at the end";
  // 0: no limit.
  PlaybackSource again(frames_, 1000.0);
  FrameLimit unlimited(again, 0);
  EXPECT_EQ(unlimited.size(), frames_.size());
  // Through the runner, as `hxmap run --camera ... --max-frames 5` does.
  PlaybackSource source(frames_, 20.0);
  FrameLimit five(source, 5);
  const RealtimeStats s = runRealtime(five, fe_, options_, stop_);
  EXPECT_EQ(s.counters.frames_in, 5u);
  EXPECT_FALSE(s.stopped_early);
}

TEST_F(RealtimeTest, ABurningJobLargerThanAnyPeriodNeverRuns) {
  test::BurnLoad burn(2, 200);  // four 50 ms periods: never fits
  options_.extra_load = &burn;
  options_.refine_workers = 0;
  FrontendParams p;
  p.feedback.enabled = false;  // its slices would count too
  p.loop_closure.enabled = false;  // so would the loop closer's
  Frontend fe(cam_, p);
  fe.setInitialPose(T0_);
  const RealtimeStats s = runRealtime(frames_, fe, options_, stop_);
  EXPECT_EQ(burn.slices(), 0u) << s.report;
  EXPECT_EQ(s.counters.slices_admitted, 0u);
  EXPECT_GT(s.counters.jobs_submitted, 0u);
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in);
}

TEST_F(RealtimeTest, RefinementJobsAreWrittenBackOrCounted) {
  FrontendParams p;
  // Small jobs (this checks the plumbing, not the field) with ample slack
  // and no shedding, so that jobs complete even under ThreadSanitizer
  // (frontend frames up to 180 ms there, 230 ms on a loaded machine, where
  // 333 ms periods left too little slack for either job to finish).
  p.refine.implicit.iterations = 6;
  p.refine.implicit.rays_per_iteration = 48;
  p.refine.implicit.max_rays = 3000;
  p.refine.implicit.bias_rays = 150;
  Frontend fe(cam_, p);
  fe.setInitialPose(T0_);
  options_.fps = 2;  // 500 ms periods
  options_.scheduler.shed_after_periods = 1000;
  options_.refine_workers = 2;
  const RealtimeStats s = runRealtime(frames_, fe, options_, stop_);
  ASSERT_GT(fe.refineJobsMade(), 0u) << "the room's keyframes choose ROIs";
  EXPECT_EQ(s.refine_jobs_submitted + s.refine_jobs_rejected + fe.refineJobsDropped(), fe.refineJobsMade()) << s.report;
  // Jobs are made only for idle workers: none waits in a ring, none is
  // turned away.
  EXPECT_EQ(s.refine_jobs_rejected, 0u) << s.report;
  EXPECT_LE(fe.refineJobsMade(), s.refine_jobs_completed + s.refine_jobs_shed + 2u) << s.report;
  EXPECT_LE(s.refine_jobs_completed + s.refine_jobs_shed, s.refine_jobs_submitted);
  EXPECT_GT(s.refine_jobs_completed, 0u) << s.report;
  EXPECT_EQ(s.refine_outcomes_dropped, 0u);
  EXPECT_GT(s.refine_voxels_written, 0u) << "completed jobs reach the map";
  EXPECT_LE(s.patches_applied, s.refine_jobs_completed);
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in);
}

TEST_F(RealtimeTest, KeyframeCorrectionsMoveTheKeyframeNotTheLivePoseAndReintegrate) {
  size_t k = 0;
  while (fe_.keyframes() < 2 && k < frames_.size()) fe_.process(frames_[k++]);
  ASSERT_EQ(fe_.keyframes(), 2u);
  const std::vector<alg::WindowKeyframe> kfs = fe_.takeFeedbackKeyframes();
  ASSERT_EQ(kfs.size(), 2u);
  EXPECT_EQ(kfs[0].id, 0u);
  EXPECT_EQ(kfs[1].id, 1u);
  EXPECT_EQ(kfs[0].camera.width, cam_.width / 2) << "feedback images at level 1";
  EXPECT_TRUE(kfs[0].odometry_information.isZero()) << "the first keyframe has no tracking";
  EXPECT_GT(kfs[1].odometry_information.trace(), 0.0);
  EXPECT_TRUE(fe_.takeFeedbackKeyframes().empty());
  const Trajectory before = fe_.trajectory();
  size_t kf1 = 0;
  while (before[kf1].stamp_ns != kfs[1].stamp_ns) ++kf1;

  // The oldest keyframe moves 1 cm: its entry only; queued for re-integration.
  KeyframeCorrection c{0, kfs[0].T_world_cam};
  c.T_world_cam.translation().x() += 0.01;
  const Eigen::Isometry3d live = fe_.lastPose();
  EXPECT_TRUE(fe_.applyKeyframeCorrection(c));
  EXPECT_NEAR((fe_.trajectory()[0].T_world_cam.translation() - c.T_world_cam.translation()).norm(), 0.0, 1e-12);
  for (size_t i = 1; i < before.size(); ++i) EXPECT_TRUE(fe_.trajectory()[i].T_world_cam.isApprox(before[i].T_world_cam));
  EXPECT_TRUE(fe_.lastPose().isApprox(live)) << "not the newest keyframe: the live pose stays";
  EXPECT_EQ(fe_.reintegrationsPending(), 1u);
  EXPECT_EQ(fe_.reintegratePending(), 1);
  EXPECT_EQ(fe_.reintegrationsPending(), 0u);
  EXPECT_EQ(fe_.feedbackCounters().reintegrations, 1u);

  // The newest keyframe moves: the live pose does not jump with it (the
  // frames that follow meet the correction in the map).
  KeyframeCorrection d{1, kfs[1].T_world_cam};
  d.T_world_cam.translation().y() -= 0.002;  // below the re-integration threshold
  EXPECT_TRUE(fe_.applyKeyframeCorrection(d));
  EXPECT_TRUE(fe_.lastPose().isApprox(live)) << "the newest keyframe: the live pose stays as well";
  EXPECT_TRUE(fe_.trajectory()[kf1].T_world_cam.isApprox(d.T_world_cam));
  EXPECT_EQ(fe_.reintegrationsPending(), 0u);
  EXPECT_FALSE(fe_.applyKeyframeCorrection({7, Eigen::Isometry3d::Identity()})) << "no such keyframe";
  EXPECT_EQ(fe_.feedbackCounters().corrections, 2u);
  EXPECT_EQ(fe_.feedbackCounters().corrections_late, 1u);
  EXPECT_EQ(fe_.trajectory().size(), before.size());
}

TEST_F(RealtimeTest, FeedbackThreadSolvesWindowsAndItsCorrectionsReachTheFrontend) {
  FrontendParams p;
  p.refine.enabled = false;
  p.quality_enabled = false;
  p.feedback.enabled = true;
  // Drifting odometry, so that the window has something to correct.
  p.odometry_bias << 0.0004, -0.0006, 0.0002, 0.0008, 0.0004, -0.0006;
  Frontend fe(cam_, p);
  fe.setInitialPose(T0_);
  options_.fps = 4;  // ample slack, also under ThreadSanitizer
  options_.scheduler.shed_after_periods = 1000;
  const RealtimeStats s = runRealtime(frames_, fe, options_, stop_);
  // Keyframes go to the feedback thread in the frontend's slack: under
  // ThreadSanitizer on a loaded machine (a 97 ms map copy, frames of 118 ms
  // at a 250 ms period) the last ones may find none before the stream ends.
  EXPECT_LE(s.keyframes_to_feedback + s.feedback_ring_full, fe.keyframes()) << s.report;
  EXPECT_GT(s.keyframes_to_feedback, 0u) << s.report;
  EXPECT_GT(s.feedback_windows_solved, 0u) << s.report;
  // One window per batch of keyframes taken (solved, or skipped at effort 0).
  EXPECT_LE(s.feedback_windows_solved + s.feedback_windows_skipped, s.keyframes_to_feedback);
  EXPECT_LE(s.corrections_applied, s.feedback_corrections_sent) << s.report;
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in);
  EXPECT_NE(s.report.find("pose feedback: window 8"), std::string::npos) << s.report;
}

TEST_F(RealtimeTest, CheckpointCopiesAreTheMapAsItWasAndAreReadOnAnotherThread) {
  // Every checkpoint is a snapshot taken on the frontend thread, its voxel
  // memory shared with the live map until the frontend writes: another
  // thread meshes it while the frontend keeps fusing (ThreadSanitizer runs
  // this test in CI), and a snapshot never changes after it was handed
  // over, voxel for voxel.
  options_.checkpoint_s = 0.05;
  std::mutex mutex;
  std::vector<MapCheckpoint> taken;
  std::vector<size_t> blocks_when_taken, triangles;
  std::vector<uint64_t> voxels_when_taken;
  const auto voxelHash = [](const alg::TsdfMap& map) {
    uint64_t h = 1469598103934665603ULL;  // FNV-1a over sdf and weight, in block order
    for (size_t i = 0; i < map.blockCount(); ++i) {
      const auto* b = reinterpret_cast<const unsigned char*>(map.block(i).geo);
      for (size_t k = 0; k < sizeof(map.block(i).geo); ++k) h = (h ^ b[k]) * 1099511628211ULL;
    }
    return h;
  };
  std::atomic<bool> done{false};
  std::thread reader([&] {
    size_t read = 0;
    while (!done.load() || read < taken.size()) {
      MapCheckpoint c;
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (read == taken.size()) {
          c.map.reset();
        } else {
          c = taken[read++];
        }
      }
      if (!c.map) {
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
        continue;
      }
      const size_t n = alg::extractMesh(*c.map, alg::MeshParams{}).triangles.size();
      std::lock_guard<std::mutex> lock(mutex);
      triangles.push_back(n);
    }
  });
  options_.on_checkpoint = [&](MapCheckpoint&& c) {
    std::lock_guard<std::mutex> lock(mutex);
    blocks_when_taken.push_back(c.map->blockCount());
    voxels_when_taken.push_back(voxelHash(*c.map));
    taken.push_back(std::move(c));
  };
  const RealtimeStats s = runRealtime(frames_, fe_, options_, stop_);
  done.store(true);
  reader.join();
  ASSERT_GE(taken.size(), 2u) << s.report;
  EXPECT_EQ(s.checkpoints, taken.size());
  EXPECT_NE(s.report.find("checkpoints: "), std::string::npos) << s.report;
  EXPECT_GT(s.checkpoint_chunks_copied, 0u) << "the frontend wrote into chunks the snapshots held";
  ASSERT_EQ(triangles.size(), taken.size());
  for (size_t k = 0; k < taken.size(); ++k) {
    EXPECT_EQ(taken[k].map->blockCount(), blocks_when_taken[k]) << "copy " << k << " changed after the hand-over";
    EXPECT_EQ(voxelHash(*taken[k].map), voxels_when_taken[k]) << "copy " << k << " changed after the hand-over";
    EXPECT_GT(triangles[k], 0u) << "copy " << k;
    EXPECT_LE(taken[k].trajectory.size(), fe_.trajectory().size());
    if (k > 0) {
      EXPECT_GE(taken[k].trajectory.size(), taken[k - 1].trajectory.size());
    }
  }
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
