#include <gtest/gtest.h>

#include "hxmap/geometry/camera.hpp"
#include "hxmap/geometry/se3.hpp"

namespace hxmap::alg {
namespace {

TEST(Se3, ExpLogRoundTrip) {
  Vector6d xi;
  xi << 0.3, -0.2, 0.5, 1.0, -2.0, 0.5;
  const Vector6d back = logSE3(expSE3(xi));
  EXPECT_LT((back - xi).norm(), 1e-9);
  EXPECT_NEAR(rotationAngle(expSE3(xi)), xi.head<3>().norm(), 1e-9);
}

TEST(Se3, ExpMatchesFirstOrderAction) {
  // exp(xi) x ~ x + omega x x + v for small xi (the ICP update convention).
  Vector6d xi;
  xi << 1e-6, -2e-6, 3e-6, 1e-6, 2e-6, -1e-6;
  const Eigen::Vector3d x(1.0, 2.0, 3.0);
  const Eigen::Vector3d expected = x + xi.head<3>().cross(x) + xi.tail<3>();
  EXPECT_LT((expSE3(xi) * x - expected).norm(), 1e-10);  // second order: |xi|^2 |x| ~ 1e-10
}

TEST(Se3, RigidityCheck) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  EXPECT_TRUE(isRigid(T));
  T(0, 0) = 1.1;
  EXPECT_FALSE(isRigid(T));
  T(0, 0) = std::nan("");
  EXPECT_FALSE(isRigid(T));
  T = Eigen::Matrix4d::Identity();
  T(2, 2) = -1;  // reflection
  EXPECT_FALSE(isRigid(T));
}

TEST(Camera, ProjectBackprojectAndLevels) {
  const PinholeCamera c{517.3, 516.5, 318.6, 255.3, 640, 480, {0, 0, 0, 0, 0}};
  const Eigen::Vector3f p = c.backproject(100.0f, 200.0f, 2.0f);
  const Eigen::Vector2f uv = c.project(p);
  EXPECT_NEAR(uv.x(), 100.0f, 1e-4f);
  EXPECT_NEAR(uv.y(), 200.0f, 1e-4f);
  const PinholeCamera l1 = c.level(1);
  EXPECT_EQ(l1.width, 320);
  EXPECT_DOUBLE_EQ(l1.fx, 517.3 / 2);
  // The center of fine pixels 0 and 1 is level-1 pixel 0.
  EXPECT_DOUBLE_EQ(l1.cx, (318.6 + 0.5) / 2 - 0.5);
}

}  // namespace
}  // namespace hxmap::alg

TEST(Se3, ALevelOpticalCameraLooksAlongXInAZUpFrame) {
  const Eigen::Isometry3d T = hxmap::alg::levelOpticalInZUp();
  EXPECT_TRUE((T.linear() * Eigen::Vector3d::UnitZ()).isApprox(Eigen::Vector3d::UnitX()));   // forward
  EXPECT_TRUE((T.linear() * Eigen::Vector3d::UnitY()).isApprox(-Eigen::Vector3d::UnitZ()));  // down
  EXPECT_TRUE((T.linear() * Eigen::Vector3d::UnitX()).isApprox(-Eigen::Vector3d::UnitY()));  // right
  EXPECT_NEAR(T.linear().determinant(), 1.0, 1e-12);
}
