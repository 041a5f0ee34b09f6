// The frontend end to end on synthetic sequences with exact ground truth,
// including frames with no depth and corrupt frames.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <thread>
#include <vector>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "commands.hpp"
#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/ply.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "stop_signals.hpp"
#include "test_data.hpp"

namespace hxmap::rt {
namespace {

const alg::PinholeCamera kCam{262.5, 262.5, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};

class Pipeline : public ::testing::Test {
 protected:
  void SetUp() override {
    sp_.frames = 45;
    sp_.camera = kCam;
    traj_ = drv::syntheticTrajectory(sp_);
  }
  RgbdFrame frame(int i) {
    const auto r = drv::renderFrame(scene_, kCam, traj_[i].T_world_cam, sp_, i);
    return {traj_[i].stamp_ns, static_cast<uint64_t>(i), r.rgb, r.depth};
  }
  drv::SyntheticScene scene_ = drv::SyntheticScene::room();
  drv::SyntheticParams sp_;
  Trajectory traj_;
};

TEST_F(Pipeline, TracksNoisySyntheticSequence) {
  Frontend fe(kCam, FrontendParams{});
  fe.setInitialPose(traj_[0].T_world_cam);
  for (int i = 0; i < sp_.frames; ++i) {
    const FrameResult r = fe.process(frame(i));
    EXPECT_TRUE(r.tracked) << "frame " << i << ": " << r.failure;
  }
  const auto ate = alg::computeAte(fe.trajectory(), traj_);
  EXPECT_LT(ate.rmse_m, 0.01) << "ATE RMSE (m)";
  EXPECT_GE(fe.keyframes(), 2u);

  // Keyframes scored the map's regions and chose ROIs within the budget,
  // each with the keyframes that observed it.
  const auto& scores = fe.blockScores();
  ASSERT_GT(scores.size(), 20u);
  for (const auto& s : scores) {
    EXPECT_GE(s.priority, 0.0f);
    EXPECT_LE(s.priority, 1.0f + 1e-6f);
  }
  size_t chosen = 0;
  for (const auto& roi : fe.rois()) {
    chosen += roi.blocks.size();
    EXPECT_FALSE(roi.keyframes.empty());
    EXPECT_LT(roi.keyframes.back(), fe.keyframes());
    EXPECT_TRUE(
        roi.box_world.contains((roi.blocks[0].cast<float>() + Eigen::Vector3f::Constant(0.5f)) * fe.map().blockSize()));
  }
  const auto& qp = FrontendParams{}.quality;
  EXPECT_EQ(chosen, std::min<size_t>(qp.max_blocks, static_cast<size_t>(std::ceil(qp.top_fraction * scores.size()))));
}

TEST_F(Pipeline, WarmUpLeavesTheFrontendAsNew) {
  // The warm-up maps synthetic frames into a scratch map: the frontend's
  // own map, trajectory and keyframes stay empty, and it then maps a
  // sequence exactly as a frontend that never warmed up.
  Frontend warm(kCam, FrontendParams{}), cold(kCam, FrontendParams{});
  warm.warmUp();
  EXPECT_EQ(warm.map().blockCount(), 0u);
  EXPECT_TRUE(warm.trajectory().empty());
  EXPECT_EQ(warm.keyframes(), 0u);
  warm.setInitialPose(traj_[0].T_world_cam);
  cold.setInitialPose(traj_[0].T_world_cam);
  for (int i = 0; i < 8; ++i) {
    const RgbdFrame f = frame(i);
    const FrameResult a = warm.process(f), b = cold.process(f);
    EXPECT_EQ(a.tracked, b.tracked);
    EXPECT_TRUE(a.T_world_cam.isApprox(b.T_world_cam, 1e-12)) << "frame " << i;
  }
  EXPECT_EQ(warm.map().blockCount(), cold.map().blockCount());
}

TEST_F(Pipeline, KeyframesMakeSelfContainedRefineJobsWhoseWriteBackStaysInTheirBox) {
  FrontendParams p;
  p.refine.implicit.iterations = 20;
  Frontend fe(kCam, p);
  fe.setInitialPose(traj_[0].T_world_cam);
  std::vector<RefineJob> jobs;
  for (int i = 0; i < sp_.frames; ++i) {
    fe.process(frame(i));
    for (auto& j : fe.takeRefineJobs()) jobs.push_back(std::move(j));
  }
  ASSERT_FALSE(jobs.empty());
  EXPECT_EQ(jobs.size(), fe.refineJobsMade());
  EXPECT_LE(jobs.size(), static_cast<size_t>(p.refine.max_jobs_per_keyframe) * fe.keyframes());
  for (const auto& j : jobs) {
    ASSERT_TRUE(j.snapshot);
    EXPECT_GT(j.snapshot->blockCount(), 0u);
    EXPECT_LE(j.snapshot->blockCount(), fe.map().blockCount());
    ASSERT_FALSE(j.keyframes.empty());
    EXPECT_LE(j.keyframes.size(), j.roi.keyframes.size());
    for (const auto& k : j.keyframes) {
      EXPECT_EQ(k.depth.type(), CV_32F);
      EXPECT_EQ(k.depth.cols, kCam.width / 2) << "half resolution";
      EXPECT_EQ(k.rgb.size(), k.depth.size());
    }
  }
  // Feedback is off: no job samples its field for the implicit channels
  // (below, they do, as with feedback on).
  for (auto& j : jobs) {
    EXPECT_FALSE(j.implicit_surface);
    j.implicit_surface = true;
  }
  // The newest job that has rays to learn from (an ROI whose keyframes see
  // it only outside the field's bounds has none, and trains 0 iterations),
  // run and applied: voxels change inside its box only.
  size_t newest = jobs.size() - 1;
  RefineOutcome o = runRefineJob(jobs[newest], p.refine.implicit);
  while (o.result.stats.iterations == 0 && newest > 0) o = runRefineJob(jobs[--newest], p.refine.implicit);
  const RefineJob& job = jobs[newest];
  EXPECT_GE(newest + 2, jobs.size()) << "the newest or the one before it trains";
  const alg::TsdfMap before = fe.map();
  EXPECT_GT(o.result.stats.iterations, 0);
  EXPECT_LE(o.result.stats.iterations, p.refine.implicit.iterations);
  ASSERT_FALSE(o.result.patch.entries.empty());
  const alg::PatchStats ps = fe.applyRefinement(o);
  EXPECT_EQ(ps.applied, o.result.patch.entries.size());
  for (const auto& e : o.result.patch.entries) {
    EXPECT_TRUE(job.roi.box_world.contains(fe.map().voxelCenter(e.voxel))) << e.voxel.transpose();
  }
  size_t changed = 0;
  for (size_t b = 0; b < before.blockCount(); ++b) {
    const int32_t a = fe.map().find(before.key(b));
    ASSERT_GE(a, 0);
    for (int i = 0; i < alg::kBlockVoxels; ++i) {
      if (before.block(b).geo[i].sdf_m == fe.map().block(static_cast<size_t>(a)).geo[i].sdf_m) continue;
      ++changed;
      const Eigen::Vector3i g = before.key(b) * alg::kBlockSide + Eigen::Vector3i(i % 8, (i / 8) % 8, i / 64);
      EXPECT_TRUE(job.roi.box_world.contains(fe.map().voxelCenter(g))) << "changed outside the ROI box";
    }
  }
  EXPECT_GT(changed, 0u);
  // sigma_Neural reached the quality map for the blocks the job rendered.
  ASSERT_FALSE(o.result.neural_sigma.empty());
  size_t scored = 0;
  for (const auto& [key, sigma] : o.result.neural_sigma) {
    const alg::BlockQuality* q = fe.quality().find(key);
    if (q == nullptr) continue;  // rendered, but not a block the quality map scores
    ++scored;
    EXPECT_FLOAT_EQ(q->sigma_neural_m, std::max(0.0f, sigma)) << key.transpose();
  }
  EXPECT_GT(scored, 0u) << "no block the job rendered is in the quality map";
  RefineJob unsampled = job;
  unsampled.implicit_surface = false;
  EXPECT_FALSE(runRefineJob(unsampled, p.refine.implicit).surface);
  // The job's field joins the pose feedback's implicit channels: a window
  // of the keyframes that saw the ROI gets implicit residuals inside it.
  ASSERT_TRUE(o.surface);
  EXPECT_GT(o.surface->sampledNodes(), 0u);
  const auto surfaces = fe.implicitSurfaces();
  ASSERT_EQ(surfaces.size(), 1u);
  EXPECT_EQ(surfaces.front().get(), o.surface.get());
  alg::FeedbackParams fp;
  fp.window = 4;
  alg::PoseWindow window(fp);
  alg::FeedbackMaps maps{&fe.map(), {surfaces.front().get()}};
  int implicit = 0;
  for (const auto& k : job.keyframes) {
    alg::WindowKeyframe w;
    w.id = k.id;
    w.camera = k.camera;
    w.T_world_cam = k.T_world_cam.cast<double>();
    w.depth = k.depth;
    w.intensity = cv::Mat(k.depth.size(), CV_32F, cv::Scalar(0.5f));
    window.add(w, maps);
    const size_t j = window.size() - 1;
    const auto L = window.linearize(j, window.keyframes()[j].T_world_cam, maps, window.basePixels(j));
    implicit += L.counts.depth_implicit;
    if (window.size() == 4) break;
  }
  EXPECT_GT(implicit, 0) << "no ray of the ROI's keyframes met its field";
  // A second job over the same box replaces the first field.
  fe.applyRefinement(runRefineJob(job, p.refine.implicit));
  ASSERT_EQ(fe.implicitSurfaces().size(), 1u);
  EXPECT_NE(fe.implicitSurfaces().front().get(), o.surface.get());
}

TEST_F(Pipeline, RefineJobsTrainOnKeyframesOlderThanTheImagePoolsLength) {
  // A pool of 4 keyframe images. It evicts the image fewest quality-map
  // blocks keep, so jobs still get views older than the last 4 keyframes
  // (a first-in first-out pool never gives them one).
  FrontendParams p;
  p.refine.keyframe_images = 4;
  Frontend fe(kCam, p);
  fe.setInitialPose(traj_[0].T_world_cam);
  size_t jobs = 0, old_images = 0;
  for (int i = 0; i < sp_.frames; ++i) {
    fe.process(frame(i));
    for (auto& j : fe.takeRefineJobs()) {
      ++jobs;
      EXPECT_LE(j.keyframes.size(), 4u);
      for (const auto& k : j.keyframes) {
        EXPECT_NE(std::find(j.roi.keyframes.begin(), j.roi.keyframes.end(), k.id), j.roi.keyframes.end());
        old_images += j.keyframe_id - k.id >= 4;
      }
    }
  }
  EXPECT_GT(jobs, 0u);
  EXPECT_GT(old_images, 0u);
}

TEST_F(Pipeline, BlankedDepthIsReportedDoesNotTouchTheMapAndRecovers) {
  Frontend fe(kCam, FrontendParams{});
  fe.setInitialPose(traj_[0].T_world_cam);
  size_t blocks_before_blank = 0;
  for (int i = 0; i < sp_.frames; ++i) {
    RgbdFrame f = frame(i);
    const bool blank = i >= 15 && i < 20;
    if (blank) f.depth.setTo(0);
    if (i == 15) blocks_before_blank = fe.map().blockCount();
    const FrameResult r = fe.process(f);
    if (blank) {
      EXPECT_FALSE(r.tracked) << "frame " << i;
      EXPECT_FALSE(r.integrated);
      EXPECT_NE(r.failure.find("valid depth"), std::string::npos) << r.failure;
      EXPECT_EQ(fe.map().blockCount(), blocks_before_blank) << "a blank frame changed the map";
    } else if (i >= 21) {
      EXPECT_TRUE(r.tracked) << "frame " << i << " did not recover: " << r.failure;
    }
  }
  EXPECT_EQ(fe.lostFrames(), 5u);
  // Tracked frames stay accurate (lost frames carry the last good pose).
  Trajectory tracked;
  for (size_t i = 0; i < fe.trajectory().size(); ++i) {
    if (i < 15 || i >= 20) tracked.push_back(fe.trajectory()[i]);
  }
  EXPECT_LT(alg::computeAte(tracked, traj_).rmse_m, 0.015);
}

TEST_F(Pipeline, CorruptFramesNeverCrash) {
  Frontend fe(kCam, FrontendParams{});
  fe.setInitialPose(traj_[0].T_world_cam);
  ASSERT_TRUE(fe.process(frame(0)).tracked);
  RgbdFrame nan = frame(1);
  for (int v = 0; v < nan.depth.rows; v += 7) {
    for (int u = 0; u < nan.depth.cols; u += 5) {
      nan.depth.at<float>(v, u) =
          (u % 2) ? std::numeric_limits<float>::quiet_NaN() : std::numeric_limits<float>::infinity();
    }
  }
  nan.depth.at<float>(5, 5) = -1.0f;
  const FrameResult rn = fe.process(nan);
  EXPECT_TRUE(rn.tracked) << "sparse NaN/inf depth must be ignored, not fatal: " << rn.failure;
  RgbdFrame wrong_size = frame(2);
  wrong_size.depth = cv::Mat(10, 10, CV_32F, cv::Scalar(1.0f));
  EXPECT_FALSE(fe.process(wrong_size).tracked);
  RgbdFrame wrong_type = frame(3);
  wrong_type.depth.convertTo(wrong_type.depth, CV_16U, 1000.0);
  EXPECT_FALSE(fe.process(wrong_type).tracked);
  RgbdFrame empty;
  EXPECT_FALSE(fe.process(empty).tracked);
  RgbdFrame no_color = frame(4);
  no_color.rgb = cv::Mat();
  EXPECT_TRUE(fe.process(no_color).tracked) << "depth alone is enough to track";
  const FrameResult r5 = fe.process(frame(5));
  EXPECT_TRUE(r5.tracked) << r5.failure;
}

// A synthetic sequence of `frames` frames seen by kCam in a fresh folder
// (empty when it could not be written).
std::string syntheticSequence(const char* name, int frames,
                         const drv::SyntheticScene& scene = drv::SyntheticScene::room()) {
  const std::string dir = test::tempDir(name);
  drv::SyntheticParams sp;
  sp.frames = frames;
  sp.camera = kCam;
  return drv::writeSyntheticSequence(dir, scene, sp) ? dir : std::string();
}

namespace {
// The program's exit status and what it printed (stdout and stderr).
std::pair<int, std::string> runProgram(const std::string& args) {
  FILE* pipe = popen(("'" HXMAP_BIN "' " + args + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return {-1, ""};
  std::string out;
  char buf[512];
  while (fgets(buf, sizeof buf, pipe) != nullptr) out += buf;
  const int status = pclose(pipe);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out};
}
}  // namespace

TEST(Program, VersionAndUsageErrorsHaveTheDocumentedExitCodes) {
  const auto [version_rc, version] = runProgram("--version");
  EXPECT_EQ(version_rc, 0);
  EXPECT_EQ(version.rfind("hxmap " HXMAP_VERSION_FOR_TEST, 0), 0u) << version;
  EXPECT_NE(version.find("built with:"), std::string::npos) << version;
  // CLI11's own codes (104-109) never leak out: a bad option is usage (2).
  EXPECT_EQ(runProgram("run --no-such-option").first, 2);
  EXPECT_EQ(runProgram("").first, 2);  // no command
  EXPECT_EQ(runProgram("synth --frames zero --out x").first, 2);
  // A negative frame count is a usage error naming the option, not "all frames".
  const auto [neg_rc, neg] = runProgram("run --dataset . --max-frames -5 --out x");
  EXPECT_EQ(neg_rc, 2);
  EXPECT_NE(neg.find("--max-frames"), std::string::npos) << neg;
  // An unwritable --trace is reported before the run, not after it.
  const auto [trace_rc, trace] = runProgram("run --dataset . --trace /proc/no/such/trace.json --out x");
  EXPECT_EQ(trace_rc, 2);
  EXPECT_NE(trace.find("--trace /proc/no/such/trace.json: cannot write there"), std::string::npos) << trace;
}

// `hxmap synth` renders with the configuration's camera when it gives one:
// the images have its size and the sequence's calibration its intrinsics.
TEST(Program, SynthRendersWithTheConfiguredCamera) {
  const std::string dir = test::tempDir("synth_camera");
  const std::string config = dir + "/c.yaml", out = dir + "/seq";
  {
    std::ofstream f(config);
    f << "camera: {fx: 260, fy: 262, cx: 159.5, cy: 119.5, width: 320, height: 240}\n";
  }
  const auto [rc, text] = runProgram("-q synth --frames 3 --config '" + config + "' --out '" + out + "'");
  ASSERT_EQ(rc, 0) << text;
  const auto loaded = drv::Dataset::open(out);
  ASSERT_TRUE(loaded) << loaded.message();
  EXPECT_DOUBLE_EQ((*loaded)->camera().fx, 260.0);
  EXPECT_DOUBLE_EQ((*loaded)->camera().fy, 262.0);
  EXPECT_EQ((*loaded)->camera().width, 320);
  const auto frame = (*loaded)->load(0);
  ASSERT_TRUE(frame) << frame.message();
  EXPECT_EQ(frame->depth.cols, 320);
  EXPECT_EQ(frame->depth.rows, 240);
  // A distorted lens is not rendered: an error naming the keys.
  {
    std::ofstream f(config);
    f << "camera: {fx: 260, fy: 262, cx: 159.5, cy: 119.5, width: 320, height: 240, k1: 0.1}\n";
  }
  const auto [bad_rc, bad] = runProgram("-q synth --frames 3 --config '" + config + "' --out '" + dir + "/bad'");
  EXPECT_EQ(bad_rc, 2);
  EXPECT_NE(bad.find("k1, k2, p1, p2, k3"), std::string::npos) << bad;
}

TEST(RunCommand, WritesOutputsAndSkipsUnreadableFramesWhenAsked) {
  const std::string data = syntheticSequence("seq", 12), out = test::tempDir("out");
  ASSERT_FALSE(data.empty());
  // Corrupt the 6th color image.
  std::string sixth;
  {
    std::ifstream in(data + "/rgb.txt");
    std::string line;
    int n = 0;
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#' && ++n == 6) sixth = line.substr(line.find(' ') + 1);
    }
  }
  std::ofstream(data + "/" + sixth, std::ios::trunc) << "garbage";

  RunOptions o;
  o.dataset = data;
  o.out_dir = out;
  o.no_mesh_eval = true;
  EXPECT_EQ(runCommand(o), 1) << "an unreadable frame stops the run unless skipping is asked";
  EXPECT_TRUE(std::filesystem::exists(out + "/trajectory.txt")) << "what was mapped is still written";

  o.skip_bad = true;
  EXPECT_EQ(runCommand(o), 2) << "the folder holds a finished run: replaced only with --overwrite";
  o.overwrite = true;
  EXPECT_EQ(runCommand(o), 0);
  std::ifstream summary(out + "/summary.txt");
  const std::string text((std::istreambuf_iterator<char>(summary)), {});
  EXPECT_NE(text.find("processed 11"), std::string::npos) << text;
  EXPECT_NE(text.find("unreadable skipped 1, bad list or ground-truth lines skipped 0"), std::string::npos) << text;
  EXPECT_NE(text.find("ATE RMSE"), std::string::npos) << text;
  EXPECT_TRUE(std::filesystem::file_size(out + "/mesh.ply") > 1000);

  // Played in real time, the frames before the bad one are mapped and
  // written too, and the run ends with 1.
  const std::string out_rt = test::tempDir("out_rt");
  o.out_dir = out_rt;
  o.skip_bad = false;
  o.realtime = true;
  EXPECT_EQ(runCommand(o), 1);
  std::ifstream rt_summary(out_rt + "/summary.txt");
  const std::string rt_text((std::istreambuf_iterator<char>(rt_summary)), {});
  // The 5 frames before the bad one reach the runtime; how many the
  // frontend keeps up with depends on the machine (sanitizers drop some).
  EXPECT_NE(rt_text.find("frames: in 5,"), std::string::npos) << rt_text;
  EXPECT_NE(rt_text.find("stopped early: "), std::string::npos) << rt_text;
  EXPECT_TRUE(std::filesystem::exists(out_rt + "/trajectory.txt"));
}

TEST(RunCommand, ARunThatMapsNothingExitsWithOneAndSaysWhy) {
  const std::string data = syntheticSequence("seq_dark", 4), out = test::tempDir("out_dark");
  ASSERT_FALSE(data.empty());
  // Every depth image all zero: no frame can be tracked or fused.
  for (const auto& entry : std::filesystem::directory_iterator(data + "/depth")) {
    ASSERT_TRUE(cv::imwrite(entry.path().string(), cv::Mat(kCam.height, kCam.width, CV_16U, cv::Scalar(0))));
  }
  // A finished run in the folder: the failed run must not replace it.
  const std::string good = syntheticSequence("seq_good", 3);
  RunOptions o;
  o.dataset = good;
  o.out_dir = out;
  o.no_mesh_eval = true;
  ASSERT_EQ(runCommand(o), 0);
  auto read = [](const std::string& path) {
    std::ifstream in(path);
    return std::string((std::istreambuf_iterator<char>(in)), {});
  };
  const std::string finished_summary = read(out + "/summary.txt"), finished_mesh = read(out + "/mesh.ply");
  ASSERT_NE(finished_summary.find("processed 3"), std::string::npos) << finished_summary;

  o.dataset = data;
  o.overwrite = true;
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(runCommand(o), 1);
  const std::string text = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(text.find("result: failed, nothing was mapped: none of the 4 frames"), std::string::npos) << text;
  EXPECT_NE(text.find(out + " left as it was: this run mapped nothing"), std::string::npos) << text;
  EXPECT_EQ(read(out + "/summary.txt"), finished_summary);
  EXPECT_EQ(read(out + "/mesh.ply"), finished_mesh);
  EXPECT_FALSE(std::filesystem::exists(out + ".partial"));
}

TEST(RunCommand, AnOutputThatCannotBeWrittenLeavesNoTemporaryAndIsNotListed) {
  const std::string data = syntheticSequence("seq_out", 3), out = test::tempDir("out_blocked");
  ASSERT_FALSE(data.empty());
  // Files larger than 16 KiB cannot be written (as on a full disk): the
  // trajectories and the summary fit, the mesh does not.
  struct rlimit before {};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &before), 0);
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  struct rlimit small = before;
  small.rlim_cur = 16 * 1024;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  RunOptions o;
  o.dataset = data;
  o.out_dir = out;
  o.no_mesh_eval = true;
  const int rc = runCommand(o);
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &before), 0);
  std::signal(SIGXFSZ, old_handler);
  EXPECT_EQ(rc, 1);
  EXPECT_FALSE(std::filesystem::exists(out + "/mesh.ply.tmp"));
  EXPECT_FALSE(std::filesystem::exists(out + "/mesh.ply"));
  std::ifstream summary(out + "/summary.txt");
  const std::string text((std::istreambuf_iterator<char>(summary)), {});
  EXPECT_NE(text.find("outputs: " + out + "/trajectory.txt, " + out + "/trajectory_live.txt\n"), std::string::npos)
      << text;
  EXPECT_NE(text.find("not written (see the errors): " + out + "/mesh.ply"), std::string::npos) << text;
}

TEST(RunCommand, AKilledRunKeepsEveryPoseItHadAndTheNextRunSaysSo) {
  // SIGKILL (the OOM killer, a watchdog) mid-run: the poses reached disk
  // frame by frame; --out is untouched; the next run keeps them aside.
  const std::string data = syntheticSequence("seq_kill", 60), out = test::tempDir("killed") + "/out";
  ASSERT_FALSE(data.empty());
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    if (!std::freopen("/dev/null", "w", stdout) || !std::freopen("/dev/null", "w", stderr)) ::_exit(126);
    ::execl(HXMAP_BIN, HXMAP_BIN, "run", "--dataset", data.c_str(), "--out", out.c_str(), "--no-mesh-eval",
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  auto poses = [](const std::string& path) {
    std::ifstream in(path);
    int n = 0;
    for (std::string line; std::getline(in, line);) n += !line.empty() && line[0] != '#';
    return n;
  };
  const std::string live = out + ".partial/trajectory_live.txt";
  for (int i = 0; i < 6000 && poses(live) < 10; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_EQ(::kill(pid, SIGKILL), 0);
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the run ended before it was killed";
  const int had = poses(live);
  EXPECT_GE(had, 10);
  EXPECT_FALSE(std::filesystem::exists(out + "/summary.txt")) << "an unfinished run is never committed";

  const auto [rc, text] = runProgram("run --dataset '" + data + "' --out '" + out + "' --max-frames 3 --no-mesh-eval");
  EXPECT_EQ(rc, 0) << text;
  EXPECT_NE(
      text.find("an earlier run into " + out + " was interrupted; what it wrote is kept in " + out + ".interrupted-"),
      std::string::npos)
      << text;
  int kept = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::filesystem::path(out).parent_path())) {
    if (e.path().filename().string().rfind("out.interrupted-", 0) == 0) {
      ++kept;
      EXPECT_EQ(poses((e.path() / "trajectory_live.txt").string()), had);
    }
  }
  EXPECT_EQ(kept, 1);
  EXPECT_EQ(poses(out + "/trajectory_live.txt"), 3);
}

TEST(RunCommand, ALiveRunCheckpointsItsMapIntoTheRunsFolder) {
  // In real time the frontend thread copies the map into its slack every
  // runtime.checkpoint_s and another thread meshes and writes it; the
  // final outputs replace the checkpoints.
  const std::string data = syntheticSequence("seq_ck", 45), dir = test::tempDir("ck");
  ASSERT_FALSE(data.empty());
  std::ofstream(dir + "/c.yaml") << "runtime: {checkpoint_s: 0.2}\n";
  RunOptions o;
  o.dataset = data;
  o.config = dir + "/c.yaml";
  o.out_dir = dir + "/out";
  o.realtime = true;
  o.fps = 15;  // 3 s of playback
  o.no_mesh_eval = true;
  ASSERT_EQ(runCommand(o), 0);
  std::ifstream in(o.out_dir + "/summary.txt");
  const std::string text((std::istreambuf_iterator<char>(in)), {});
  const size_t at = text.find("checkpoints: ");
  ASSERT_NE(at, std::string::npos) << text;
  EXPECT_GE(std::stoi(text.substr(at + 13)), 3) << text.substr(at, 120);
  EXPECT_TRUE(std::filesystem::file_size(o.out_dir + "/mesh.ply") > 1000);
  EXPECT_FALSE(std::filesystem::exists(o.out_dir + ".partial"));
}

TEST(RunCommand, HangUpStopsTheRunLikeTermination) {
  // An ssh session that drops sends SIGHUP: the run stops and writes its
  // outputs instead of dying with nothing written.
  const StopSignals signals;
  EXPECT_FALSE(g_stop.load());
  ASSERT_EQ(std::raise(SIGHUP), 0);
  EXPECT_TRUE(g_stop.load());
  g_stop.store(false);
  ASSERT_EQ(std::raise(SIGTERM), 0);
  EXPECT_TRUE(g_stop.load());
  g_stop.store(false);
}

TEST(RunCommand, OfflineRunsGiveTheSameOutputsUnderLoad) {
  // Refinement jobs with a wall-clock budget far below their cost: offline
  // they run to their iteration cap all the same, so a run beside a CPU
  // burner writes the same trajectory and mesh, byte for byte.
  const std::string data = syntheticSequence("seq_det", 24, drv::SyntheticScene::qualityRoom());
  ASSERT_FALSE(data.empty());
  const std::string cfg = data + "/budget.yaml";
  std::ofstream(cfg) << "refine:\n  time_budget_ms: 5\n  iterations: 30\n";
  auto run = [&](const std::string& out) {
    RunOptions o;
    o.dataset = data;
    o.out_dir = out;
    o.config = cfg;
    o.no_mesh_eval = true;
    EXPECT_EQ(runCommand(o), 0);
    std::ifstream summary(out + "/summary.txt");
    return std::string((std::istreambuf_iterator<char>(summary)), {});
  };
  auto read = [](const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), {});
  };
  const std::string quiet = test::tempDir("out_det_quiet"), loaded = test::tempDir("out_det_loaded");
  const std::string text = run(quiet);
  ASSERT_NE(text.find("refinement: "), std::string::npos) << "no refinement job ran: " << text;
  std::atomic<bool> stop{false};
  std::vector<std::thread> burners;
  for (int i = 0; i < 2; ++i) {
    burners.emplace_back([&] {
      volatile double x = 1;
      while (!stop.load()) x = x * 1.0000001 + 1e-9;
    });
  }
  run(loaded);
  stop = true;
  for (auto& t : burners) t.join();
  EXPECT_EQ(read(quiet + "/trajectory.txt"), read(loaded + "/trajectory.txt"));
  EXPECT_EQ(read(quiet + "/mesh.ply"), read(loaded + "/mesh.ply"));
}

TEST(RunCommand, BadConfigAndMissingDatasetAreUsageErrors) {
  RunOptions o;
  o.dataset = "/nonexistent/dataset";
  o.out_dir = test::tempDir("out");
  EXPECT_EQ(runCommand(o), 2);
  const std::string cfg = o.out_dir + "/bad.yaml";
  std::ofstream(cfg) << "tsdf:\n  voxel: 1\n";
  o.config = cfg;
  EXPECT_EQ(runCommand(o), 2);
  // A trace that could not be written is refused before the run, not after.
  o.config.clear();
  o.dataset = syntheticSequence("seq_for_trace", 2);
  ASSERT_FALSE(o.dataset.empty());
  o.trace = "/nonexistent/folder/trace.json";
  EXPECT_EQ(runCommand(o), 2);
  EXPECT_FALSE(std::filesystem::exists(o.out_dir + "/summary.txt"));
}

TEST(RunCommand, AnExceptionThatReachesTheTopIsAnErrorExitNotAnAbort) {
  EXPECT_EQ(runReportingExceptions([]() -> int { throw std::runtime_error("out of range"); }), 1);
  EXPECT_EQ(runReportingExceptions([]() -> int { throw 42; }), 1);
  EXPECT_EQ(runReportingExceptions([] { return 2; }), 2);
  EXPECT_EQ(runReportingExceptions([] { return 0; }), 0);
}

TEST(SynthCommand, BadSceneTrajectoryOrScaleAreUsageErrorsAndWriteNothing) {
  SynthOptions o;
  o.out_dir = test::tempDir("synth_bad") + "/seq";
  o.frames = 2;
  o.scale = 0.01;  // below 0.05
  EXPECT_EQ(synthCommand(o), 2);
  o.scale = -1;
  o.scene = "castle";
  EXPECT_EQ(synthCommand(o), 2);
  o.scene = "quality";
  o.trajectory = "spiral";
  EXPECT_EQ(synthCommand(o), 2);
  EXPECT_FALSE(std::filesystem::exists(o.out_dir));
  o.trajectory = "inspect";
  o.scale = 0.5;
  ASSERT_EQ(synthCommand(o), 0);
  std::ifstream calib(o.out_dir + "/calibration.yaml");
  std::string first;
  std::getline(calib, first);
  EXPECT_NE(first.find("scale 0.5"), std::string::npos) << first;
}

}  // namespace
}  // namespace hxmap::rt

namespace hxmap::rt {
namespace {

std::string writeText(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
  return path;
}

TEST(EvalCommand, IdenticalTrajectoriesAndRigidOffset) {
  const std::string dir = test::tempDir("eval");
  const std::string gt = writeText(dir + "/gt.txt",
                                   "# t tx ty tz qx qy qz qw\n"
                                   "1.0 0 0 0 0 0 0 1\n1.1 1 0 0 0 0 0 1\n1.2 1 1 0 0 0 0 1\n1.3 0 1 1 0 0 0 1\n");
  // The same path moved by 1 m along z and turned 90 degrees about z.
  const std::string moved = writeText(dir + "/moved.txt",
                                      "1.0 0 0 1 0 0 0.7071068 0.7071068\n1.1 0 1 1 0 0 0.7071068 0.7071068\n"
                                      "1.2 -1 1 1 0 0 0.7071068 0.7071068\n1.3 -1 0 2 0 0 0.7071068 0.7071068\n");
  EvalOptions o;
  o.traj = gt;
  o.gt_traj = gt;
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(evalCommand(o), 0);
  std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find("ATE RMSE 0.00 cm"), std::string::npos) << out;
  o.traj = moved;
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(evalCommand(o), 0);
  out = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find("ATE RMSE 0.00 cm"), std::string::npos) << out;
  EXPECT_NE(out.find("RPE over 1.00 s: n/a"), std::string::npos) << "0.3 s of poses: " << out;
  o.traj = dir + "/missing.txt";
  EXPECT_EQ(evalCommand(o), 2);
}

TEST(EvalCommand, WhatCannotBeScoredIsNotApplicableAndAFailure) {
  const std::string dir = test::tempDir("eval_na");
  const std::string gt = writeText(dir + "/gt.txt", "1.0 0 0 0 0 0 0 1\n1.1 1 0 0 0 0 0 1\n1.2 1 1 0 0 0 0 1\n");
  const std::string later = writeText(dir + "/later.txt", "5.0 0 0 0 0 0 0 1\n5.1 1 0 0 0 0 0 1\n5.2 1 1 0 0 0 0 1\n");
  const std::string huge =
      writeText(dir + "/huge.txt", "1.0 1e308 0 0 0 0 0 1\n1.1 -1e308 0 0 0 0 0 1\n1.2 1e308 1e308 0 0 0 0 1\n");
  EvalOptions o;
  o.gt_traj = gt;
  for (const std::string& traj : {later, huge}) {
    o.traj = traj;
    ::testing::internal::CaptureStdout();
    EXPECT_EQ(evalCommand(o), 1) << traj;
    const std::string out = ::testing::internal::GetCapturedStdout();
    EXPECT_NE(out.find("ATE: n/a"), std::string::npos) << out;
    EXPECT_EQ(out.find("nan"), std::string::npos) << out;
  }
  EvalOptions m;
  m.mesh = dir + "/empty.ply";
  m.gt_mesh = dir + "/room.ply";
  m.samples = 2000;
  ASSERT_TRUE(drv::writePly(m.mesh, alg::TriangleMesh{}));
  ASSERT_TRUE(drv::writePly(m.gt_mesh, drv::SyntheticScene::room().mesh()));
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(evalCommand(m), 1);
  const std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find("n/a (the reconstruction is empty)"), std::string::npos) << out;
  EXPECT_EQ(out.find("accuracy"), std::string::npos) << out;
}

}  // namespace
}  // namespace hxmap::rt

namespace hxmap::rt {
namespace {

TEST(RigConfig, TheRigSectionBecomesACalibrationFramesRegisterWith) {
  const std::string yaml =
      "rig:\n  color_fx: 300\n  color_fy: 300\n  color_cx: 159.5\n  color_cy: 119.5\n  color_width: 320\n"
      "  color_height: 240\n  depth_fx: 300\n  depth_fy: 300\n  depth_cx: 159.5\n  depth_cy: 119.5\n"
      "  depth_width: 320\n  depth_height: 240\n  depth_to_color_tx: 0.04\n  depth_scale: 5000\n";
  auto c = loadConfigFromString(yaml, "rig.yaml");
  ASSERT_TRUE(c) << c.message();
  const drv::RigCalibration cal = rigCalibration(*c);
  EXPECT_DOUBLE_EQ(cal.color.fx, 300);
  EXPECT_EQ(cal.depth.width, 320);
  EXPECT_NEAR(cal.T_color_depth.translation().x(), 0.04, 1e-12);
  EXPECT_LT((cal.T_color_depth.linear() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  auto assembler = drv::FrameAssembler::create(cal);
  ASSERT_TRUE(assembler) << assembler.message();
  // A plane at 2 m (raw 10000 at 5000 per meter) lands 300 * 0.04 / 2 = 6 px to the right.
  drv::ColorImage color{5, 0, cv::Mat(240, 320, CV_8UC3, cv::Scalar(9, 9, 9))};
  drv::DepthImage depth{6, 0, cv::Mat(240, 320, CV_16UC1, cv::Scalar(10000))};
  auto f = assembler->assemble(color, depth, 0);
  ASSERT_TRUE(f) << f.message();
  EXPECT_FLOAT_EQ(f->depth.at<float>(100, 200), 2.0f);
  EXPECT_EQ(f->depth.at<float>(100, 3), 0.0f);

  auto bad = loadConfigFromString("rig:\n  depth_to_color_qw: 0.5\n", "bad_rig.yaml");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.message().find("bad_rig.yaml: rig.depth_to_color_q{x,y,z,w}: the quaternion's norm is 0.500000"),
            std::string::npos)
      << bad.message();
}

}  // namespace
}  // namespace hxmap::rt
