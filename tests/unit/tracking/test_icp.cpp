#include <limits>

#include <gtest/gtest.h>

#include "hxmap/tracking/icp.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/raycast.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::alg {
namespace {

class IcpTest : public ::testing::Test {
 protected:
  void SetUp() override {
    scene_ = drv::SyntheticScene::room();
    drv::SyntheticParams sp;
    sp.frames = 60;
    traj_ = drv::syntheticTrajectory(sp);
  }

  // Map from exact frames at ground-truth poses [first, last], in a world
  // frame moved by `world` (the same images, other coordinates).
  TsdfMap buildMap(int first, int last, double voxel_m,
                   const Eigen::Isometry3d& world = Eigen::Isometry3d::Identity()) {
    TsdfParams tp;
    tp.voxel_size_m = voxel_m;
    tp.truncation_m = 4 * voxel_m;
    TsdfMap map(tp);
    for (int i = first; i <= last; i += 2) {
      const auto f = test::syntheticFrame(scene_, cam_, traj_[i].T_world_cam);
      const auto pre = preprocessFrame(f, cam_, pp_);
      integrate(map, {pre.depth_m, pre.rgb, pre.levels[pre.finest].confidence, cam_,
                      (world * traj_[i].T_world_cam).cast<float>()});
    }
    return map;
  }

  std::vector<ModelView> modelAt(const TsdfMap& map, const Eigen::Isometry3d& T_world_cam) {
    std::vector<ModelView> model{raycast(map, cam_, T_world_cam.cast<float>(), RaycastParams{})};
    for (int l = 1; l < 3; ++l) model.push_back(subsampleView(model.back()));
    return model;
  }

  drv::SyntheticScene scene_;
  Trajectory traj_;
  PinholeCamera cam_;
  PreprocessParams pp_;
};

TEST_F(IcpTest, RecoversKnownPerturbation) {
  const TsdfMap map = buildMap(20, 40, 0.01);
  const Eigen::Isometry3d T_ref = traj_[30].T_world_cam;
  Vector6d xi;
  xi << 0.01, -0.008, 0.012, 0.02, -0.015, 0.01;  // ~0.9 deg, ~2.7 cm
  const Eigen::Isometry3d T_true = expSE3(xi) * T_ref;
  const auto frame = test::syntheticFrame(scene_, cam_, T_true);
  const auto pre = preprocessFrame(frame, cam_, pp_);
  TrackingParams tp;
  tp.iterations_finest = 10;
  const IcpResult r = trackPointToPlane(pre, modelAt(map, T_ref), T_ref, tp);
  ASSERT_TRUE(r.ok) << r.failure;
  const Eigen::Isometry3d E = T_true.inverse() * r.T_world_cam;
  EXPECT_LT(translationNorm(E), 0.001) << "translation error (m)";
  EXPECT_LT(rotationAngle(E) * 180.0 / M_PI, 0.1) << "rotation error (deg)";
}

TEST_F(IcpTest, FarFromTheMapsOriginTheSameViewIsAsWellConstrained) {
  // The same frames mapped with the world's origin beside the camera and
  // 80 m away (a long flight): tracking must neither fail nor call the
  // view degenerate there (the update turns about the world's origin; the
  // degeneracy test must not).
  Eigen::Isometry3d far = Eigen::Isometry3d::Identity();
  far.translation() = Eigen::Vector3d(60.0, -50.0, 8.0);
  Vector6d xi;
  xi << 0.01, -0.008, 0.012, 0.02, -0.015, 0.01;
  double ratio[2] = {0, 0};
  for (int k = 0; k < 2; ++k) {
    const Eigen::Isometry3d world = k == 0 ? Eigen::Isometry3d::Identity() : far;
    const TsdfMap map = buildMap(20, 40, 0.01, world);
    const Eigen::Isometry3d T_ref = world * traj_[30].T_world_cam;
    const Eigen::Isometry3d T_true = T_ref * expSE3(xi);  // the same motion in the camera's frame
    const auto pre = preprocessFrame(test::syntheticFrame(scene_, cam_, traj_[30].T_world_cam * expSE3(xi)), cam_, pp_);
    TrackingParams tp;
    tp.iterations_finest = 10;
    const IcpResult r = trackPointToPlane(pre, modelAt(map, T_ref), T_ref, tp);
    ASSERT_TRUE(r.ok) << (k ? "far: " : "near: ") << r.failure;
    const Eigen::Isometry3d E = T_true.inverse() * r.T_world_cam;
    EXPECT_LT(translationNorm(E), 0.001) << "translation error (m)";
    ratio[k] = r.min_eigen_ratio;
  }
  EXPECT_NEAR(ratio[1], ratio[0], 0.1 * ratio[0]) << "smallest/largest eigenvalue near and far from the origin";
}

TEST_F(IcpTest, PhotometricTermAloneRecoversPerturbation) {
  // The photometric term weighted far above point-to-plane must recover the
  // motion between two exact frames by itself.
  const TsdfMap map = buildMap(20, 40, 0.01);
  const Eigen::Isometry3d T_ref = traj_[30].T_world_cam;
  Vector6d xi;
  xi << 0.004, -0.003, 0.005, 0.01, -0.008, 0.006;
  const Eigen::Isometry3d T_true = expSE3(xi) * T_ref;
  const auto ref = preprocessFrame(test::syntheticFrame(scene_, cam_, T_ref), cam_, pp_);
  const auto pre = preprocessFrame(test::syntheticFrame(scene_, cam_, T_true), cam_, pp_);
  TrackingParams tp;
  tp.iterations_finest = 15;
  tp.photometric_scale_m = 100.0;
  tp.min_consistent_ratio_lost = 0.0;
  const IcpResult r = trackPointToPlane(pre, modelAt(map, T_ref), T_ref, tp, {&ref, T_ref});
  const Eigen::Isometry3d E = T_true.inverse() * r.T_world_cam;
  EXPECT_LT(translationNorm(E), 0.002) << "translation error (m)";
  EXPECT_LT(rotationAngle(E) * 180.0 / M_PI, 0.1) << "rotation error (deg)";
}

TEST_F(IcpTest, ReportsTheSpreadOfBothResidualsForTheirWeighting) {
  // The frontend weighs the photometric term by the ratio of the two
  // spreads; color noise must show in the photometric one only.
  const TsdfMap map = buildMap(20, 40, 0.01);
  const Eigen::Isometry3d T_ref = traj_[30].T_world_cam;
  const Eigen::Isometry3d T_true = traj_[31].T_world_cam;
  const auto ref = preprocessFrame(test::syntheticFrame(scene_, cam_, T_ref), cam_, pp_);
  RgbdFrame frame = test::syntheticFrame(scene_, cam_, T_true);
  TrackingParams tp;
  const IcpResult clean = trackPointToPlane(preprocessFrame(frame, cam_, pp_), modelAt(map, T_ref), T_ref, tp, {&ref, T_ref});
  cv::Mat noise(frame.rgb.size(), CV_16SC3);
  cv::randn(noise, 0, 20);  // 8 % of the range
  cv::Mat noisy;
  frame.rgb.convertTo(noisy, CV_16SC3);
  noisy += noise;
  noisy.convertTo(frame.rgb, CV_8UC3);
  const auto pre_noisy = preprocessFrame(frame, cam_, pp_);
  const IcpResult r = trackPointToPlane(pre_noisy, modelAt(map, T_ref), T_ref, tp, {&ref, T_ref});
  const IcpResult geometry_only = trackPointToPlane(pre_noisy, modelAt(map, T_ref), T_ref, tp);
  ASSERT_TRUE(clean.ok && r.ok && geometry_only.ok) << clean.failure << r.failure << geometry_only.failure;
  EXPECT_GT(clean.photometric_mean_abs, 0.0);
  // Exact frames still differ by the renderer's texture aliasing between
  // views (0.025 here); the noise adds to that.
  EXPECT_GT(r.photometric_mean_abs, 1.3 * clean.photometric_mean_abs);
  EXPECT_NEAR(r.mean_abs_residual_m, clean.mean_abs_residual_m, 0.3 * clean.mean_abs_residual_m);
  EXPECT_LT(clean.mean_abs_residual_m, 0.003);  // exact depth, a 1 cm map
  EXPECT_EQ(geometry_only.photometric_mean_abs, 0.0);
}

TEST_F(IcpTest, FrameToFrameFallbackAloneFollowsANoisySequence) {
  // Each frame tracked against the previous one only (frameAsModel), with
  // the photometric term, never against a map: 40 noisy frames of the orbit
  // (1.3 s, 0.5 m) drift less than 1 cm and 0.5 deg.
  TrackingParams tp;
  Eigen::Isometry3d T_world_cam = traj_[0].T_world_cam;
  PreprocessedFrame previous = preprocessFrame(test::syntheticFrame(scene_, cam_, T_world_cam, true, 0), cam_, pp_);
  for (int i = 1; i < 40; ++i) {
    const PreprocessedFrame pre =
        preprocessFrame(test::syntheticFrame(scene_, cam_, traj_[i].T_world_cam, true, i), cam_, pp_);
    const IcpResult r =
        trackPointToPlane(pre, frameAsModel(previous, T_world_cam), T_world_cam, tp, {&previous, T_world_cam});
    ASSERT_TRUE(r.ok) << "frame " << i << ": " << r.failure;
    T_world_cam = r.T_world_cam;
    previous = pre;
  }
  const Eigen::Isometry3d E = traj_[39].T_world_cam.inverse() * T_world_cam;
  std::printf("frame to frame over 39 frames: %.2f mm, %.3f deg\n", 1000 * translationNorm(E),
              rotationAngle(E) * 180.0 / M_PI);
  EXPECT_LT(translationNorm(E), 0.01) << "m after 39 frames";
  EXPECT_LT(rotationAngle(E) * 180.0 / M_PI, 0.5) << "deg";
}

TEST_F(IcpTest, ReportsFailureWithoutDepth) {
  const TsdfMap map = buildMap(20, 24, 0.02);
  auto frame = test::syntheticFrame(scene_, cam_, traj_[22].T_world_cam);
  frame.depth.setTo(0);
  const auto pre = preprocessFrame(frame, cam_, pp_);
  const IcpResult r = trackPointToPlane(pre, modelAt(map, traj_[22].T_world_cam), traj_[22].T_world_cam, {});
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.failure.find("inliers"), std::string::npos) << r.failure;
}

TEST(Keyframes, MotionAndTime) {
  TrackingParams p;
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d moved = I;
  moved.translation().x() = 0.2;
  EXPECT_TRUE(isNewKeyframe(I, moved, 0, 1, p));
  EXPECT_FALSE(isNewKeyframe(I, I, 0, 100'000'000, p));
  EXPECT_TRUE(isNewKeyframe(I, I, 0, 2'000'000'000, p));
  // Parallax: 6 cm is a keyframe 1 m from the scene (ratio 0.04), not 2.5 m.
  EXPECT_EQ(p.keyframe_baseline_ratio, 0.0);  // off by default
  p.keyframe_baseline_ratio = 0.04;
  moved.translation().x() = 0.06;
  EXPECT_TRUE(isNewKeyframe(I, moved, 0, 1, p, 1.0));
  EXPECT_FALSE(isNewKeyframe(I, moved, 0, 1, p, 2.5));
  EXPECT_FALSE(isNewKeyframe(I, moved, 0, 1, p));  // depth unknown: 10 cm
  p.keyframe_baseline_ratio = 0;
  EXPECT_FALSE(isNewKeyframe(I, moved, 0, 1, p, 1.0));
  // In voxels: 6 cm is a keyframe at 1 cm voxels (5 voxels), not at 2 cm;
  // at 4 cm voxels the 10 cm in meters still holds.
  EXPECT_EQ(p.keyframe_translation_voxels, 5.0);
  EXPECT_TRUE(isNewKeyframe(I, moved, 0, 1, p, 0.0, 0.01));
  EXPECT_FALSE(isNewKeyframe(I, moved, 0, 1, p, 0.0, 0.02));
  moved.translation().x() = 0.12;
  EXPECT_TRUE(isNewKeyframe(I, moved, 0, 1, p, 0.0, 0.04));
  moved.translation().x() = 0.06;
  p.keyframe_translation_voxels = 0;
  EXPECT_FALSE(isNewKeyframe(I, moved, 0, 1, p, 0.0, 0.01));
}

TEST(Keyframes, MedianDepthSkipsInvalidPixels) {
  cv::Mat d(2, 4, CV_32F, cv::Scalar(0.0f));
  d.at<float>(0, 0) = 1.0f;
  d.at<float>(0, 1) = std::numeric_limits<float>::quiet_NaN();
  d.at<float>(1, 0) = 3.0f;
  d.at<float>(1, 1) = 2.0f;
  d.at<float>(1, 2) = std::numeric_limits<float>::infinity();
  EXPECT_FLOAT_EQ(medianDepth(d), 2.0f);
  EXPECT_EQ(medianDepth(cv::Mat(3, 3, CV_32F, cv::Scalar(0.0f))), 0.0f);
}

}  // namespace
}  // namespace hxmap::alg
