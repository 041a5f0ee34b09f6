#include <gtest/gtest.h>

#include "hxmap/eval/mesh_metrics.hpp"
#include "hxmap/eval/triangle_bvh.hpp"

namespace hxmap::alg {
namespace {

// A w x h plane at height z, split into n x n quads.
TriangleMesh plane(float w, float h, float z, int n) {
  TriangleMesh m;
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) m.vertices.emplace_back(w * i / n, h * j / n, z);
  }
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i;
      m.triangles.emplace_back(a, a + 1, a + n + 2);
      m.triangles.emplace_back(a, a + n + 2, a + n + 1);
    }
  }
  return m;
}

TEST(TriangleBvh, DistanceAndRaycastMatchBruteForce) {
  const TriangleMesh m = plane(2, 2, 0.5f, 7);
  const TriangleBvh bvh(m);
  EXPECT_NEAR(bvh.distance({1.0f, 1.0f, 0.8f}), 0.3f, 1e-6f);
  EXPECT_NEAR(bvh.distance({3.0f, 1.0f, 0.5f}), 1.0f, 1e-6f);  // off the edge
  EXPECT_NEAR(bvh.raycast({1.0f, 1.0f, 2.0f}, {0, 0, -1}, 0.0f, 10.0f), 1.5f, 1e-6f);
  EXPECT_EQ(bvh.raycast({1.0f, 1.0f, 2.0f}, {0, 0, 1}, 0.0f, 10.0f), 10.0f);
}

TEST(MeshMetrics, MeshAgainstItselfIsPerfect) {
  const TriangleMesh m = plane(10, 8, 0, 20);  // the surface area of a room
  MeshMetricsParams p;
  const MeshMetrics r = computeMeshMetrics(m, m, p);
  EXPECT_DOUBLE_EQ(r.point_to_surface.f1_fine, 1.0);
  EXPECT_LT(r.point_to_surface.accuracy_cm, 1e-4);
  // The point-to-sampled-point variant is sampling-limited at 1 cm: with
  // 200k samples on 80 m^2 the samples are ~2 cm apart.
  EXPECT_LT(r.point_to_point.f1_fine, 0.8);
  EXPECT_GT(r.point_to_point.f1_coarse, 0.999);
}

TEST(MeshMetrics, PlaneMovedTwoCentimeters) {
  const TriangleMesh gt = plane(2, 2, 0, 10);
  const TriangleMesh rec = plane(2, 2, 0.02f, 10);
  MeshMetricsParams p;
  p.samples = 50000;
  const MeshMetrics r = computeMeshMetrics(rec, gt, p);
  EXPECT_LT(r.point_to_surface.precision_fine, 0.01);
  EXPECT_GT(r.point_to_surface.precision_coarse, 0.99);
  EXPECT_NEAR(r.point_to_surface.accuracy_cm, 2.0, 0.01);
}

// One camera 2 m above the middle of the unit square at z = 0, looking down.
ObservedBy lookingDownAtTheUnitSquare() {
  ObservedBy obs;
  obs.camera = PinholeCamera{300, 300, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};
  StampedPose pose;
  pose.T_world_cam.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
  pose.T_world_cam.translation() = Eigen::Vector3d(0.5, 0.5, 2.0);
  obs.poses = {pose};
  return obs;
}

TEST(MeshMetrics, UnobservedGroundTruthIsExcluded) {
  // Two planes; the camera looks only at the first, from above.
  TriangleMesh gt = plane(1, 1, 0, 4);
  TriangleMesh far = plane(1, 1, 0, 4);
  for (auto& v : far.vertices) v.x() += 10;
  gt.append(far);
  const TriangleMesh rec = plane(1, 1, 0, 4);
  ObservedBy obs = lookingDownAtTheUnitSquare();
  MeshMetricsParams p;
  p.samples = 20000;
  const MeshMetrics with = computeMeshMetrics(rec, gt, p, &obs);
  const MeshMetrics without = computeMeshMetrics(rec, gt, p);
  EXPECT_GT(with.point_to_surface.recall_fine, 0.99);
  EXPECT_NEAR(without.point_to_surface.recall_fine, 0.5, 0.02);
}

TEST(MeshMetrics, GroundTruthSeenOnlyAtGrazingIncidenceIsExcludedWhenTheSensorCannotMeasureIt) {
  // A floor seen from 2 m above, and a 10 cm high wall standing on it that
  // the same camera sees nearly edge-on (|cos(incidence)| about 0.05).
  TriangleMesh gt = plane(1, 1, 0, 4);
  TriangleMesh wall = plane(1, 0.1f, 0, 4);
  for (auto& v : wall.vertices) v = Eigen::Vector3f(0.6f, v.x(), v.y());
  gt.append(wall);
  const TriangleMesh rec = plane(1, 1, 0, 4);  // the floor alone
  ObservedBy obs = lookingDownAtTheUnitSquare();
  MeshMetricsParams p;
  p.samples = 20000;
  const MeshMetrics any_angle = computeMeshMetrics(rec, gt, p, &obs);
  obs.min_abs_cos = 0.1;
  const MeshMetrics measurable = computeMeshMetrics(rec, gt, p, &obs);
  // The wall is ~9% of the ground truth; its lowest centimeter lies within
  // 1 cm of the floor.
  EXPECT_NEAR(any_angle.point_to_surface.recall_fine, 1.0 - 0.09 * 0.9, 0.02);
  EXPECT_GT(measurable.point_to_surface.recall_fine, 0.995);
  EXPECT_LT(measurable.ground_truth_samples, any_angle.ground_truth_samples);
  // At a cut-off below the wall's incidence it counts again.
  obs.min_abs_cos = 0.02;
  EXPECT_EQ(computeMeshMetrics(rec, gt, p, &obs).ground_truth_samples, any_angle.ground_truth_samples);
}

}  // namespace
}  // namespace hxmap::alg
