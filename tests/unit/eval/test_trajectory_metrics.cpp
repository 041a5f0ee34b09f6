#include <gtest/gtest.h>

#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/geometry/se3.hpp"

namespace hxmap::alg {
namespace {

Trajectory wiggle(int n, int64_t dt_ns) {
  Trajectory t;
  for (int i = 0; i < n; ++i) {
    StampedPose p;
    p.stamp_ns = 1'000'000'000LL + i * dt_ns;
    Vector6d xi;
    xi << 0.1 * std::sin(0.1 * i), 0.05 * i * 0.01, 0.02 * std::cos(0.2 * i), 0.01 * i, std::sin(0.05 * i), 0.3;
    p.T_world_cam = expSE3(xi);
    t.push_back(p);
  }
  return t;
}

TEST(Ate, IdenticalTrajectoriesGiveZero) {
  const Trajectory t = wiggle(100, 33'333'333);
  const AteResult r = computeAte(t, t);
  EXPECT_EQ(r.pairs, 100u);
  EXPECT_LT(r.rmse_m, 1e-9);
  const RpeResult rpe = computeRpe(t, t, 1'000'000'000LL);
  EXPECT_GT(rpe.pairs, 50u);
  EXPECT_LT(rpe.trans_rmse_m, 1e-9);
}

TEST(Ate, RemovesKnownRigidOffset) {
  const Trajectory gt = wiggle(100, 33'333'333);
  Vector6d xi;
  xi << 0.3, -0.5, 1.2, 2.0, -1.0, 0.5;
  const Eigen::Isometry3d offset = expSE3(xi);
  Trajectory est = gt;
  for (auto& p : est) p.T_world_cam = offset * p.T_world_cam;
  const AteResult r = computeAte(est, gt);
  EXPECT_LT(r.rmse_m, 1e-6);
  EXPECT_LT((r.T_gt_est.matrix() - offset.inverse().matrix()).norm(), 1e-6);
}

TEST(Ate, KnownErrorAfterAlignment) {
  // A constant 1 cm offset along x on alternate poses: RMSE stays near 5 mm
  // after alignment (half of it removed by the mean).
  const Trajectory gt = wiggle(100, 33'333'333);
  Trajectory est = gt;
  for (size_t i = 0; i < est.size(); i += 2) est[i].T_world_cam.translation().x() += 0.01;
  const AteResult r = computeAte(est, gt);
  EXPECT_NEAR(r.rmse_m, 0.005, 0.0005);
}

TEST(Association, GreedyClosestFirstWithinWindow) {
  const std::vector<int64_t> a = {1000, 2000, 3000, 10000};
  const std::vector<int64_t> b = {1010, 1990, 2005, 9000};
  AssociationParams p;
  p.max_difference_ns = 20;
  const auto m = associateStamps(a, b, p);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0], (std::pair<size_t, size_t>(0, 0)));
  EXPECT_EQ(m[1], (std::pair<size_t, size_t>(1, 2)));  // 2005 is 5 away, 1990 is 10 away
}

TEST(Interpolation, MidpointBetweenSamples) {
  Trajectory t(2);
  t[0].stamp_ns = 0;
  t[1].stamp_ns = 100;
  t[1].T_world_cam.translation() = Eigen::Vector3d(1, 0, 0);
  Eigen::Isometry3d T;
  ASSERT_TRUE(interpolatePose(t, 25, 1000, T));
  EXPECT_NEAR(T.translation().x(), 0.25, 1e-12);
  EXPECT_FALSE(interpolatePose(t, 200, 1000, T));
  EXPECT_FALSE(interpolatePose(t, 50, 10, T));  // gap too large
}

}  // namespace
}  // namespace hxmap::alg
