// A live camera through the real-time runner without hardware: two
// stand-in UVC devices (YUYV color, Z16 depth) pace themselves at 30 FPS
// and show the synthetic room along its ground-truth trajectory. The frames
// go through the grabber threads, stream pairing, registration, the sensor
// and frontend threads; the trajectory is scored against the ground truth.
// Also: the depth camera unplugged mid-run and back (the gap is counted, the
// run goes on), a camera that stalls (the run ends with an error naming it,
// outputs intact), and the spec parser.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>

#include "hxmap/camera/camera_source.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "scripted_v4l2.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::rt {
namespace {

constexpr int64_t kPeriodNs = 33'333'333;

class CameraSourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto scene = drv::SyntheticScene::room();
    drv::SyntheticParams sp;
    sp.frames = kFrames;
    traj_ = drv::syntheticTrajectory(sp);
    for (size_t i = 0; i < traj_.size(); ++i) {
      const RgbdFrame f = test::syntheticFrame(scene, cam_, traj_[i].T_world_cam, false, static_cast<int>(i));
      yuyv_.push_back(drv::encodeYuyv(f.rgb));
      cv::Mat mm;
      f.depth.convertTo(mm, CV_16UC1, 1000.0);
      z16_.emplace_back(reinterpret_cast<const uint8_t*>(mm.data),
                        reinterpret_cast<const uint8_t*>(mm.data) + mm.total() * mm.elemSize());
    }
    color_ = makeDevice(V4L2_PIX_FMT_YUYV, yuyv_);
    depth_ = makeDevice(V4L2_PIX_FMT_Z16, z16_);
    options_.calibration.color = cam_;
    options_.calibration.depth = cam_;
    options_.calibration.registered = true;  // the stand-ins render depth in the color camera
    options_.fps = 30;
    options_.lost_timeout_s = 0.6;
    options_.reconnect_timeout_s = 3;
    run_options_.status_interval_s = 0;
    // The scripted devices stream from the moment they are opened, and
    // these tests count every frame: a frontend warm-up (seconds under the
    // sanitizers) would leave the first frames to be dropped by the driver.
    run_options_.warm_up = false;
    run_options_.background_nice = 0;  // beside other test processes (see test_realtime.cpp)
  }

  std::shared_ptr<test::ScriptedDevice> makeDevice(uint32_t format, const std::vector<std::vector<uint8_t>>& frames) {
    auto dev = std::make_shared<test::ScriptedDevice>();
    dev->formats = {format};
    dev->width = cam_.width;
    dev->height = cam_.height;
    dev->period_ns = kPeriodNs;
    dev->last_index = frames.size() - 1;
    dev->fill = [&frames](uint64_t index, std::vector<uint8_t>& buf) {
      const auto& src = frames[std::min<size_t>(index, frames.size() - 1)];
      std::copy(src.begin(), src.begin() + static_cast<std::ptrdiff_t>(std::min(src.size(), buf.size())), buf.begin());
    };
    return dev;
  }

  /// The ground truth on the color camera's clock.
  Trajectory groundTruth() const {
    Trajectory gt;
    for (size_t i = 0; i < traj_.size(); ++i) {
      gt.push_back({color_->firstStreamOnNs() + static_cast<int64_t>(i) * kPeriodNs, traj_[i].T_world_cam});
    }
    return gt;
  }

  static constexpr int kFrames = 60;
  const alg::PinholeCamera cam_{160, 160, 79.5, 59.5, 160, 120, {0, 0, 0, 0, 0}};
  Trajectory traj_;
  std::vector<std::vector<uint8_t>> yuyv_, z16_;
  std::shared_ptr<test::ScriptedDevice> color_, depth_;
  CameraSourceOptions options_;
  RealtimeOptions run_options_;
  std::atomic<bool> stop_{false};
};

TEST_F(CameraSourceTest, AV4l2PairMapsTheRoomInRealTimeAndAStalledCameraEndsTheRun) {
  const CameraSpec spec{CameraSpec::Kind::kV4l2Pair, "/dev/video-color", "/dev/video-depth"};
  auto source = openCameraSource(spec, options_, color_, depth_);
  ASSERT_TRUE(source) << source.message();
  EXPECT_EQ((*source)->camera().width, 160);
  Frontend fe(cam_, FrontendParams{});
  fe.setInitialPose(traj_.front().T_world_cam);
  const RealtimeStats s = runRealtime(**source, fe, run_options_, stop_);
  // The devices stall after their last frame: the source ends with an error
  // naming the silent device, after the frames were all handed over.
  EXPECT_NE(s.source_error.find("/dev/video-"), std::string::npos) << s.source_error;
  EXPECT_NE(s.source_error.find("delivered nothing"), std::string::npos) << s.source_error;
  EXPECT_EQ(s.counters.frames_processed + s.counters.frames_dropped, s.counters.frames_in) << s.report;
  // Every frame the cameras gave was paired (same clock, 30 FPS both):
  // at most the last one can be left waiting for a later depth frame.
  EXPECT_GE(s.counters.frames_in, static_cast<uint64_t>(kFrames - 1)) << s.report;
  EXPECT_GE(s.counters.frames_processed, 10u) << s.report;  // the rest dropped when the frontend is behind (sanitizers)
  EXPECT_NE(s.report.find("source: V4L2 color /dev/video-color"), std::string::npos) << s.report;
  // Tracking on the live frames: the poses follow the ground truth.
  const alg::AteResult ate = alg::computeAte(fe.trajectory(), groundTruth());
  EXPECT_GE(ate.pairs, s.counters.frames_processed - 1);
  EXPECT_LT(ate.rmse_m, 0.02) << s.report;
}

TEST_F(CameraSourceTest, ADepthCameraUnpluggedMidRunComesBackWithTheGapCounted) {
  depth_->unplug_at = 20;           // after 20 frames
  depth_->opens_before_return = 3;  // back after about 0.3 s
  const CameraSpec spec{CameraSpec::Kind::kV4l2Pair, "/dev/video-color", "/dev/video-depth"};
  auto source = openCameraSource(spec, options_, color_, depth_);
  ASSERT_TRUE(source) << source.message();
  Frontend fe(cam_, FrontendParams{});
  fe.setInitialPose(traj_.front().T_world_cam);
  const RealtimeStats s = runRealtime(**source, fe, run_options_, stop_);
  EXPECT_NE(s.report.find("/dev/video-depth (scripted UVC camera): 0 lost by the driver, 0 corrupt, 1 reconnects"),
            std::string::npos)
      << s.report;
  // Color frames without depth while it was away were dropped by the pairing,
  // the rest mapped: frames after the gap were processed.
  EXPECT_LT(s.counters.frames_in, static_cast<uint64_t>(kFrames - 3)) << s.report;
  EXPECT_GT(s.counters.frames_in, static_cast<uint64_t>(kFrames / 2)) << s.report;
  ASSERT_FALSE(s.results.empty());
  const int64_t gap_end_ns = color_->firstStreamOnNs() + 30 * kPeriodNs;
  EXPECT_GT(s.results.back().stamp_ns, gap_end_ns) << "frames after the reconnect are mapped";
  const alg::AteResult ate = alg::computeAte(fe.trajectory(), groundTruth());
  EXPECT_LT(ate.rmse_m, 0.03) << s.report;
}

TEST_F(CameraSourceTest, StopEndsALiveRunPromptly) {
  const CameraSpec spec{CameraSpec::Kind::kV4l2Pair, "/dev/video-color", "/dev/video-depth"};
  options_.lost_timeout_s = 30;
  auto source = openCameraSource(spec, options_, color_, depth_);
  ASSERT_TRUE(source) << source.message();
  Frontend fe(cam_, FrontendParams{});
  std::thread stopper([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    stop_.store(true);
  });
  const auto t0 = std::chrono::steady_clock::now();
  const RealtimeStats s = runRealtime(**source, fe, run_options_, stop_);
  stopper.join();
  const double took_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(s.stopped_early);
  EXPECT_TRUE(s.source_error.empty()) << s.source_error;
  EXPECT_LT(took_s, 5.0) << "a stop is seen within a grab timeout, not after lost_timeout_s";
  EXPECT_EQ(fe.trajectory().size(), s.counters.frames_processed);
}

TEST(CameraSpecTest, ParsesTheThreeFormsAndNamesWhatIsWrong) {
  auto v = parseCameraSpec("v4l2:/dev/video4+/dev/video2");
  ASSERT_TRUE(v) << v.message();
  EXPECT_EQ(v->kind, CameraSpec::Kind::kV4l2Pair);
  EXPECT_EQ(v->color, "/dev/video4");
  EXPECT_EQ(v->depth, "/dev/video2");
  auto o = parseCameraSpec("openni2");
  ASSERT_TRUE(o);
  EXPECT_EQ(o->kind, CameraSpec::Kind::kOpenNi2);
  EXPECT_TRUE(o->color.empty());
  EXPECT_EQ(parseCameraSpec("openni2:walk.oni")->color, "walk.oni");
  auto l = parseCameraSpec("libcamera:/base/soc/i2c0/imx219@10+v4l2:/dev/video2");
  ASSERT_TRUE(l) << l.message();
  EXPECT_EQ(l->kind, CameraSpec::Kind::kLibcameraV4l2);
  EXPECT_EQ(l->color, "/base/soc/i2c0/imx219@10");
  EXPECT_EQ(l->depth, "/dev/video2");
  EXPECT_EQ(parseCameraSpec("libcamera+v4l2:/dev/video2")->color, "");
  for (const char* bad : {"v4l2:/dev/video0", "v4l2:/dev/video0+/dev/video0", "v4l2:+/dev/video1", "kinect",
                          "libcamera", "libcamera+v4l2:", "libcameraX+v4l2:/dev/video1"}) {
    auto e = parseCameraSpec(bad);
    ASSERT_FALSE(e) << bad;
    EXPECT_NE(e.message().find(std::string("camera '") + bad + "'"), std::string::npos) << e.message();
    EXPECT_NE(e.message().find("the forms are"), std::string::npos) << e.message();
  }
}

TEST(CameraSourceErrors, MissingDevicesAndSizeMismatchesAreClearErrors) {
  CameraSourceOptions o;
  o.calibration.color = {525, 525, 319.5, 239.5, 640, 480, {0, 0, 0, 0, 0}};
  o.calibration.depth = o.calibration.color;
  auto missing = openCameraSource({CameraSpec::Kind::kV4l2Pair, "/dev/video-hxmap-missing", "/dev/video-hxmap-gone"}, o);
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.message().find("/dev/video-hxmap-missing: cannot open the camera"), std::string::npos)
      << missing.message();
  // The device streams 64x48 but the rig says 640x480.
  auto small = std::make_shared<test::ScriptedDevice>();
  auto depth = std::make_shared<test::ScriptedDevice>();
  depth->formats = {V4L2_PIX_FMT_Z16};
  auto mismatch = openCameraSource({CameraSpec::Kind::kV4l2Pair, "/dev/video-a", "/dev/video-b"}, o, small, depth);
  ASSERT_FALSE(mismatch);
  EXPECT_NE(mismatch.message().find("streams 64x48, but rig.color_width/color_height say 640x480"), std::string::npos)
      << mismatch.message();
}

}  // namespace
}  // namespace hxmap::rt
