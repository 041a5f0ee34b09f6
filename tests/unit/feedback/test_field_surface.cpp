// The neural field as the pose feedback's implicit surface: rays meet the
// sampled field where the field itself has its zero crossing, with the
// field's gradient as normal and its color; rays outside the sampled band
// or the box find nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "hxmap/feedback/field_surface.hpp"
#include "hxmap/tsdf/integrate.hpp"

namespace hxmap::alg {
namespace {

const PinholeCamera kCam{80, 80, 39.5, 29.5, 80, 60, {0, 0, 0, 0, 0}};

// A map of the tilted plane z = 0.5 + 0.2 x (camera at the origin looking down +z).
TsdfMap planeMap() {
  TsdfParams p;
  p.voxel_size_m = 0.02f;
  p.truncation_m = 0.06;
  p.integration_level = 0;
  TsdfMap map(p);
  for (const float dx : {-0.05f, 0.0f, 0.05f}) {
    DepthObservation obs;
    obs.camera = kCam;
    obs.T_world_cam = Eigen::Isometry3f::Identity();
    obs.T_world_cam.translation() = Eigen::Vector3f(dx, 0, 0);
    obs.depth_m = cv::Mat(kCam.height, kCam.width, CV_32F, cv::Scalar(0.0f));
    obs.rgb = cv::Mat(kCam.height, kCam.width, CV_8UC3, cv::Scalar(90, 120, 150));
    for (int v = 0; v < kCam.height; ++v) {
      for (int u = 0; u < kCam.width; ++u) {
        const Eigen::Vector3f q = kCam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
        // (dx + z qx) * 0.2 + 0.5 = z
        obs.depth_m.at<float>(v, u) = (0.5f + 0.2f * dx) / (1.0f - 0.2f * q.x());
      }
    }
    integrate(map, obs);
  }
  return map;
}

// The field's first + to - crossing along the ray by dense 0.5 mm steps.
float fieldCrossing(const NeuralField& f, const Eigen::Vector3f& o, const Eigen::Vector3f& d, float t0, float t1) {
  const int n = static_cast<int>((t1 - t0) / 0.0005f) + 1;
  Eigen::Matrix3Xf pts(3, n);
  for (int i = 0; i < n; ++i) pts.col(i) = o + (t0 + 0.0005f * static_cast<float>(i)) * d;
  Eigen::VectorXf s;
  f.forward(pts, s, nullptr, nullptr);
  for (int i = 1; i < n; ++i) {
    if (s[i - 1] > 0 && s[i] <= 0) return t0 + 0.0005f * (static_cast<float>(i) - 1 + s[i - 1] / (s[i - 1] - s[i]));
  }
  return NAN;
}

TEST(FieldSurface, RaysMeetTheFieldsSurfaceWithItsGradientAndColor) {
  const TsdfMap map = planeMap();
  ImplicitParams p;
  p.fuse_width = 8;
  p.hidden_width = 16;
  const Eigen::Vector3i vmin = map.voxelOf(Eigen::Vector3f(-0.12f, -0.12f, 0.40f));
  NeuralField field(map, vmin, Eigen::Vector3i(12, 12, 12), p);
  // A trained-looking field: the decoder adds a smooth correction.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-0.3f, 0.3f);
  auto& P = field.parameters();
  for (size_t i = field.gridParameters(); i < P.size(); ++i) P[i] += 0.1f * u(rng);
  const FieldSurface surface(field);
  ASSERT_GT(surface.sampledNodes(), 1000u);
  // A band, not the box. (The default band, 3 voxels, is the truncation
  // here, 6 cm: it holds all but the nodes whose interpolated distance
  // rounds above it, so the check takes a narrower one.)
  const FieldSurface narrow(field, 1.5f);
  EXPECT_GT(narrow.sampledNodes(), 500u);
  EXPECT_LT(narrow.sampledNodes(), static_cast<size_t>(field.fineGrid().nodeCount()) * 2 / 3);

  const Eigen::Vector3f o = Eigen::Vector3f::Zero();
  int checked = 0;
  double worst_t = 0, worst_deg = 0, worst_rgb = 0;
  for (int v = 20; v < 40; v += 3) {
    for (int uu = 30; uu < 50; uu += 3) {
      const Eigen::Vector3f d = kCam.backproject(static_cast<float>(uu), static_cast<float>(v), 1.0f).normalized();
      const float t_plane = 0.5f / (d.z() - 0.2f * d.x());
      const float t_ref = fieldCrossing(field, o, d, t_plane - 0.05f, t_plane + 0.05f);
      if (!std::isfinite(t_ref) || !field.box().contains(o + t_ref * d)) continue;
      float t = 0;
      Eigen::Vector3f n, rgb;
      ASSERT_TRUE(surface.intersect(o, d, t_plane + 0.01f, t, n, rgb)) << uu << "," << v;
      worst_t = std::max(worst_t, static_cast<double>(std::abs(t - t_ref)));
      // The field's gradient by central differences.
      const float h = 0.002f;
      Eigen::Matrix3Xf pts(3, 7);
      const Eigen::Vector3f x = o + t_ref * d;
      pts.col(0) = x;
      for (int a = 0; a < 3; ++a) {
        pts.col(1 + 2 * a) = x + h * Eigen::Vector3f::Unit(a);
        pts.col(2 + 2 * a) = x - h * Eigen::Vector3f::Unit(a);
      }
      Eigen::VectorXf s;
      Eigen::Matrix3Xf c;
      field.forward(pts, s, &c, nullptr);
      const Eigen::Vector3f g((s[1] - s[2]) / (2 * h), (s[3] - s[4]) / (2 * h), (s[5] - s[6]) / (2 * h));
      const double cosang = std::clamp(static_cast<double>(n.normalized().dot(g.normalized())), -1.0, 1.0);
      worst_deg = std::max(worst_deg, std::acos(cosang) * 180.0 / M_PI);
      worst_rgb = std::max(worst_rgb, static_cast<double>((rgb - 255.0f * c.col(0).cwiseMax(0.0f).cwiseMin(1.0f)).cwiseAbs().maxCoeff()));
      ++checked;
    }
  }
  std::printf("%d rays: worst |t - t_field| %.2f mm, normal %.2f deg, rgb %.2f\n", checked, 1000 * worst_t, worst_deg,
              worst_rgb);
  EXPECT_GT(checked, 30);
  // Samples half a voxel (1 cm) apart of a smooth field.
  EXPECT_LT(worst_t, 0.001) << "m";
  EXPECT_LT(worst_deg, 3.0) << "deg";
  EXPECT_LT(worst_rgb, 3.0) << "of 255";
}

TEST(FieldSurface, NothingOutsideTheBandOrTheBox) {
  const TsdfMap map = planeMap();
  ImplicitParams p;
  const Eigen::Vector3i vmin = map.voxelOf(Eigen::Vector3f(-0.12f, -0.12f, 0.40f));
  const NeuralField field(map, vmin, Eigen::Vector3i(12, 12, 12), p);
  const FieldSurface surface(field);
  float t = 0;
  Eigen::Vector3f n, rgb;
  const Eigen::Vector3f d = Eigen::Vector3f::UnitZ();
  EXPECT_TRUE(surface.intersect(Eigen::Vector3f::Zero(), d, 0.5f, t, n, rgb));
  EXPECT_NEAR(t, 0.5f, 0.004f);  // the TSDF's plane (the untrained field)
  // A hint far from the surface: the band around it was not sampled.
  EXPECT_FALSE(surface.intersect(Eigen::Vector3f::Zero(), d, 0.3f, t, n, rgb));
  // A ray beside the box.
  EXPECT_FALSE(surface.intersect(Eigen::Vector3f(1.0f, 0, 0), d, 0.5f, t, n, rgb));
  float s = 0;
  EXPECT_FALSE(surface.sample(Eigen::Vector3f(0, 0, 2.0f), s, nullptr, nullptr));
}

}  // namespace
}  // namespace hxmap::alg
