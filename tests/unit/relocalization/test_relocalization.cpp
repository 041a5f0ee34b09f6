// The keyframe database: a frame near a kept keyframe gets its pose back
// from ORB matches and PnP + RANSAC; a frame of another scene gets none.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "hxmap/geometry/se3.hpp"
#include "hxmap/relocalization/keyframe_database.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::alg {
namespace {

const PinholeCamera kCam{525.0, 525.0, 319.5, 239.5, 640, 480, {0, 0, 0, 0, 0}};

FrameFeatures featuresOf(const RgbdFrame& f, const RelocalizationParams& p, bool require_depth = true) {
  cv::Mat gray;
  cv::cvtColor(f.rgb, gray, cv::COLOR_RGB2GRAY);
  return extractFeatures(gray, f.depth, kCam, p, require_depth);
}

class Relocalization : public ::testing::Test {
 protected:
  void SetUp() override {
    drv::SyntheticParams sp;
    sp.frames = 300;
    traj_ = drv::syntheticTrajectory(sp);
  }
  /// Keyframes every 30 frames (1 s) of the orbit's first 4 s.
  KeyframeDatabase orbitDatabase() const {
    KeyframeDatabase db(params_);
    for (int i : {0, 30, 60, 90, 120}) {
      const RgbdFrame f = test::syntheticFrame(scene_, kCam, traj_[static_cast<size_t>(i)].T_world_cam, true, i);
      db.add(static_cast<uint32_t>(i), featuresOf(f, params_), traj_[static_cast<size_t>(i)].T_world_cam);
    }
    return db;
  }
  drv::SyntheticScene scene_ = drv::SyntheticScene::room();
  Trajectory traj_;
  RelocalizationParams params_;
};

TEST_F(Relocalization, RecoversTheFramesPoseFromANearbyKeyframe) {
  const KeyframeDatabase db = orbitDatabase();
  // 10 frames (a third of a second, about 12 cm and 5 degrees) past the
  // keyframe at 60; the ranking hint is far off, as after a blackout.
  const int query = 70;
  const FrameFeatures f = featuresOf(test::syntheticFrame(scene_, kCam, traj_[query].T_world_cam, true, query),
                                     params_, false);
  std::string why;
  const auto c = db.query(f, kCam, Eigen::Isometry3d::Identity(), 0, &why);
  ASSERT_FALSE(c.empty()) << why;
  const Eigen::Isometry3d E = traj_[query].T_world_cam.inverse() * c.front().T_world_cam;
  EXPECT_LT(translationNorm(E), 0.01) << "m, from keyframe " << c.front().keyframe_id << " with "
                                      << c.front().pnp_inliers << " inliers of " << c.front().matches;
  EXPECT_LT(rotationAngle(E) * 180.0 / M_PI, 1.0) << "deg";
}

TEST_F(Relocalization, RefusesAFrameOfAnotherRoom) {
  const KeyframeDatabase db = orbitDatabase();
  // Another room: the quality room at 1.7 times the size, its walls and
  // floor with each other's textures, seen from the sweep path.
  drv::SyntheticParams sp;
  sp.frames = 60;
  sp.trajectory = "sweep";
  sp.scale = 1.7;
  const Trajectory other = drv::syntheticTrajectory(sp);
  drv::SyntheticScene room = drv::SyntheticScene::qualityRoom().scaled(1.7f);
  for (auto& pr : room.mutablePrimitives()) pr.texture = pr.texture == 1 ? 2 : pr.texture == 2 ? 1 : 0;
  for (int i : {0, 30, 59}) {
    const FrameFeatures f = featuresOf(test::syntheticFrame(room, kCam, other[i].T_world_cam, true, i), params_, false);
    std::string why;
    const auto c = db.query(f, kCam, other[i].T_world_cam, 0, &why);
    EXPECT_TRUE(c.empty()) << "frame " << i << ": keyframe " << c.front().keyframe_id << ", " << c.front().pnp_inliers
                           << " inliers of " << c.front().matches;
    EXPECT_FALSE(why.empty());
  }
}

TEST_F(Relocalization, TheDatabaseIsBoundedAndKeepsSpreadViews) {
  RelocalizationParams p = params_;
  p.max_keyframes = 3;
  KeyframeDatabase db(p);
  FrameFeatures f;
  f.descriptors = cv::Mat(1, 32, CV_8U, cv::Scalar(7));
  f.pixels = {{1, 1}};
  f.points_cam = {Eigen::Vector3f(0, 0, 1)};
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  for (uint32_t id = 0; id < 4; ++id) {
    T_world_cam.translation().x() = id == 1 ? 0.01 : static_cast<double>(id);  // keyframe 1 sits next to keyframe 0
    db.add(id, f, T_world_cam);
  }
  EXPECT_EQ(db.size(), 3u);
  EXPECT_FALSE(db.updatePose(0, T_world_cam) && db.updatePose(1, T_world_cam))
      << "one of the two near-duplicates must have gone";
  EXPECT_TRUE(db.updatePose(3, T_world_cam)) << "the newest stays";
}

}  // namespace
}  // namespace hxmap::alg
