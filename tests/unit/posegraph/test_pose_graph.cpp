// The pose graph recovers known keyframe poses from noisy relative factors
// once a loop closes, and a wrong closure beside right ones does not pull it.
#include <random>

#include <gtest/gtest.h>

#include "hxmap/posegraph/pose_graph.hpp"

using namespace hxmap::alg;

namespace {

// Keyframes around a circle of radius 2 m, looking at its center.
std::vector<Eigen::Isometry3d> circle(int n) {
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < n; ++i) {
    const double a = 2.0 * M_PI * i / n;
    Eigen::Isometry3d T_world_kf = Eigen::Isometry3d::Identity();
    T_world_kf.linear() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T_world_kf.translation() = Eigen::Vector3d(2.0 * std::cos(a), 2.0 * std::sin(a), 0.1 * std::sin(3 * a));
    poses.push_back(T_world_kf);
  }
  return poses;
}

struct Loop {
  std::vector<Eigen::Isometry3d> truth;
  PoseGraph graph;
};

// Odometry with noise (0.5 deg, 8 mm per axis per step): the chained
// estimate drifts by about a decimeter around the circle.
Loop drifted(int n, uint32_t seed) {
  Loop l;
  l.truth = circle(n);
  std::mt19937 rng(seed);
  std::normal_distribution<double> rot(0.0, 0.5 * M_PI / 180.0), trans(0.0, 0.008);
  Eigen::Isometry3d T_world_kf = l.truth[0];
  l.graph.setNode(0, T_world_kf);
  const Matrix6d info = isotropicInformation(0.5 * M_PI / 180.0, 0.008);
  for (int i = 1; i < n; ++i) {
    Vector6d xi;
    xi << rot(rng), rot(rng), rot(rng), trans(rng), trans(rng), trans(rng);
    const Eigen::Isometry3d meas = l.truth[i - 1].inverse() * l.truth[i] * expSE3(xi);
    T_world_kf = T_world_kf * meas;
    l.graph.setNode(static_cast<uint32_t>(i), T_world_kf);
    EXPECT_TRUE(l.graph.addFactor({static_cast<uint32_t>(i - 1), static_cast<uint32_t>(i), meas, info, false}));
  }
  return l;
}

double error(const Loop& l, size_t i) {
  return (l.graph.node(static_cast<uint32_t>(i)).translation() - l.truth[i].translation()).norm();
}

double rmsError(const Loop& l) {
  double e = 0;
  for (size_t i = 0; i < l.truth.size(); ++i) e += error(l, i) * error(l, i);
  return std::sqrt(e / static_cast<double>(l.truth.size()));
}

}  // namespace

TEST(PoseGraph, ALoopFactorRecoversKnownPosesFromDriftedOdometry) {
  Loop l = drifted(60, 1);
  const double end_before = error(l, 59), rms_before = rmsError(l);
  ASSERT_GT(end_before, 0.10);  // the drift to undo
  const uint32_t last = 59;
  const Matrix6d loop_info = isotropicInformation(0.2 * M_PI / 180.0, 0.003);
  const double gate = std::sqrt(22.46);  // chi-square, 6 degrees of freedom, 99.9 %
  const PoseGraphFactor loop{last, 0, l.truth[last].inverse() * l.truth[0], loop_info, true};
  const double error_before = l.graph.whitenedError(loop);
  PoseGraphReport r = l.graph.addLoop(loop, 0, gate);
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  EXPECT_FALSE(r.refused) << r.max_whitened_error;
  EXPECT_LT(r.cost_after, 0.01 * r.cost_before);
  r = l.graph.addLoop({last - 1, 1, l.truth[last - 1].inverse() * l.truth[1], loop_info, true}, 0, gate);
  EXPECT_FALSE(r.refused) << r.max_whitened_error;
  EXPECT_LT(l.graph.whitenedError(loop), 0.1 * error_before);
  // The loop's end comes back to within the closure's noise; what remains
  // elsewhere is the odometry's noise between the loop's ends (a random
  // walk tied at both ends).
  EXPECT_LT(error(l, 59), 0.015) << "before: " << end_before;
  EXPECT_LT(rmsError(l), 0.6 * rms_before) << "before: " << rms_before;
  EXPECT_NEAR((l.graph.node(0).translation() - l.truth[0].translation()).norm(), 0.0, 1e-9);  // the gauge
}

TEST(PoseGraph, AWrongClosureBesideRightOnesIsRefusedAndLeavesTheGraphAsItWas) {
  Loop l = drifted(60, 2);
  const double end_before = error(l, 59), rms_before = rmsError(l);
  const Matrix6d loop_info = isotropicInformation(0.2 * M_PI / 180.0, 0.003);
  const double gate = std::sqrt(22.46);
  for (uint32_t k = 0; k < 4; ++k) {
    EXPECT_FALSE(l.graph.addLoop({59 - k, k, l.truth[59 - k].inverse() * l.truth[k], loop_info, true}, 0, gate).refused);
  }
  const auto nodes = l.graph.nodes();
  const size_t factors = l.graph.factors().size();
  // A place that looks the same, 1.5 m away.
  Eigen::Isometry3d wrong = l.truth[40].inverse() * l.truth[10];
  wrong.translation() += Eigen::Vector3d(1.5, 0.0, 0.0);
  const PoseGraphReport r = l.graph.addLoop({40, 10, wrong, loop_info, true}, 0, gate);
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  EXPECT_TRUE(r.refused);
  EXPECT_GT(r.max_whitened_error, gate);
  ASSERT_EQ(l.graph.factors().size(), factors);
  for (const auto& [id, T] : nodes) EXPECT_TRUE(l.graph.node(id).isApprox(T)) << id;
  ASSERT_GT(end_before, 0.10);
  EXPECT_LT(error(l, 59), 0.015) << "before: " << end_before;
  EXPECT_LT(rmsError(l), 0.6 * rms_before) << "before: " << rms_before;
}

TEST(PoseGraph, FixedNodesStayWhereTheyAreAndTheOthersTakeTheCorrection) {
  // The first 20 keyframes as a saved map holds them (fixed); the drift of
  // the rest is undone by a closure on keyframe 0.
  Loop l = drifted(60, 2);
  std::vector<Eigen::Isometry3d> saved;
  for (uint32_t i = 0; i < 20; ++i) {
    l.graph.fixNode(i);
    saved.push_back(l.graph.node(i));
  }
  EXPECT_TRUE(l.graph.isFixed(19));
  EXPECT_FALSE(l.graph.isFixed(20));
  const double end_before = error(l, 59);
  ASSERT_GT(end_before, 0.10);
  const Matrix6d loop_info = isotropicInformation(0.2 * M_PI / 180.0, 0.003);
  const PoseGraphReport r =
      l.graph.addLoop({59, 0, l.truth[59].inverse() * l.truth[0], loop_info, true}, 0, std::sqrt(22.46));
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  EXPECT_FALSE(r.refused) << r.max_whitened_error;
  for (uint32_t i = 0; i < 20; ++i) {
    EXPECT_TRUE(l.graph.node(i).isApprox(saved[i], 1e-12)) << "fixed node " << i << " moved";
  }
  EXPECT_LT(error(l, 59), 0.3 * end_before);
}

TEST(PoseGraph, RefusesFactorsBetweenUnknownNodesAndAnUnknownGauge) {
  PoseGraph g;
  g.setNode(0, Eigen::Isometry3d::Identity());
  EXPECT_FALSE(g.addFactor({0, 1, Eigen::Isometry3d::Identity(), Matrix6d::Identity(), false}));
  EXPECT_FALSE(g.addFactor({0, 0, Eigen::Isometry3d::Identity(), Matrix6d::Identity(), false}));
  EXPECT_FALSE(g.optimize(7).failure.empty());
  EXPECT_FALSE(g.addLoop({0, 5, Eigen::Isometry3d::Identity(), Matrix6d::Identity(), true}, 0, 5.0).failure.empty());
}

TEST(PoseGraph, ShapedInformationKeepsTheBestDirectionsSigmaAndWeakensTheOthers) {
  // A registration that pins rotation and x, z well and y a hundred times less.
  Vector6d h;
  h << 1e6, 1e6, 1e6, 4e6, 4e4, 4e6;
  const Matrix6d shaped = shapedInformation(h.asDiagonal(), 0.01, 0.01);
  // In units of the sigmas (1/0.01^2 = 1e4) the best direction has 1; y a
  // hundredth of x's; the rotations a quarter of the best translation's.
  EXPECT_NEAR(shaped(3, 3), 1e4, 1e-6);
  EXPECT_NEAR(shaped(4, 4), 1e2, 1e-6);
  EXPECT_NEAR(shaped(0, 0), 0.25e4, 1e-6);
  EXPECT_NEAR(shapedInformation(h.asDiagonal(), 0.01, 0.01, 0.5)(4, 4), 0.5e4, 1e-6);  // the floor
  // Not positive definite: the isotropic information.
  Vector6d bad = h;
  bad(4) = 0;
  EXPECT_TRUE(shapedInformation(bad.asDiagonal(), 0.01, 0.02).isApprox(isotropicInformation(0.01, 0.02)));
}
