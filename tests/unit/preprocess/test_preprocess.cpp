#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <Eigen/Geometry>

#include "hxmap/preprocess/preprocess.hpp"

namespace hxmap::alg {
namespace {

// The filter as specified, one pixel at a time with std::exp.
cv::Mat plainBilateral(const cv::Mat& depth, const PreprocessParams& p) {
  const int r = p.bilateral_radius_px;
  cv::Mat out(depth.size(), CV_32F, cv::Scalar(0));
  for (int v = 0; v < depth.rows; ++v) {
    for (int u = 0; u < depth.cols; ++u) {
      const double z = depth.at<float>(v, u);
      if (z <= 0) continue;
      const double sr = p.bilateral_sigma_depth_factor * depthSigma(static_cast<float>(z), p);
      double sum = 0, wsum = 0;
      for (int dy = -r; dy <= r; ++dy) {
        for (int dx = -r; dx <= r; ++dx) {
          const int vv = v + dy, uu = u + dx;
          if (vv < 0 || uu < 0 || vv >= depth.rows || uu >= depth.cols) continue;
          const double zn = depth.at<float>(vv, uu);
          if (zn <= 0) continue;
          const double x = (zn - z) * (zn - z) / (2 * sr * sr);
          if (x > 4.5) continue;
          const double w =
              std::exp(-(dx * dx + dy * dy) / (2 * p.bilateral_sigma_px * p.bilateral_sigma_px)) * std::exp(-x);
          sum += w * zn;
          wsum += w;
        }
      }
      out.at<float>(v, u) = static_cast<float>(sum / wsum);
    }
  }
  return out;
}

// A noisy slanted plane with a step (another surface), holes and a border.
cv::Mat testDepth() {
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.004f);
  std::uniform_real_distribution<float> hole(0.0f, 1.0f);
  cv::Mat d(61, 83, CV_32F);
  for (int v = 0; v < d.rows; ++v) {
    for (int u = 0; u < d.cols; ++u) {
      float z = 1.0f + 0.004f * static_cast<float>(u) + 0.002f * static_cast<float>(v) + noise(rng);
      if (u > 40) z += 0.3f;
      d.at<float>(v, u) = hole(rng) < 0.1f ? 0.0f : z;
    }
  }
  return d;
}

TEST(Preprocess, BilateralFilterAgreesWithThePlainDefinition) {
  const PreprocessParams p;
  const cv::Mat depth = testDepth();
  const cv::Mat fast = bilateralDepth(depth, p);
  const cv::Mat plain = plainBilateral(depth, p);
  double max_err = 0;
  for (int v = 0; v < depth.rows; ++v) {
    for (int u = 0; u < depth.cols; ++u) {
      const float z = depth.at<float>(v, u), f = fast.at<float>(v, u);
      ASSERT_TRUE(std::isfinite(f)) << u << "," << v;
      if (z <= 0) {
        EXPECT_EQ(f, 0.0f) << "an invalid pixel stays invalid at " << u << "," << v;
        continue;
      }
      max_err = std::max(max_err, static_cast<double>(std::abs(f - plain.at<float>(v, u))));
    }
  }
  // Weights differ by at most 4e-4 relative; the depths averaged span a few
  // noise sigmas (millimetres), so the means agree to micrometres.
  EXPECT_LT(max_err, 2e-6);
}

TEST(Preprocess, NormalsAgreeWithThePlainDefinition) {
  // computeNormals runs a branch-free row kernel the compiler vectorizes
  // (SSE or AVX2 on x86-64, NEON on arm64). The definition, one pixel at a
  // time in double: n = (R - L) x (B - T) normalized and turned towards the
  // camera, where the pixel and its four neighbours have depth and neither
  // pair jumps by more than 2 * edge_jump_sigmas noise sigmas at the
  // pixel's depth; (0, 0, 0) elsewhere and on the border.
  const PreprocessParams p;
  PinholeCamera cam;
  const cv::Mat depth = testDepth();
  cam.width = depth.cols;
  cam.height = depth.rows;
  cam.cx = 0.5 * (depth.cols - 1);
  cam.cy = 0.5 * (depth.rows - 1);
  const cv::Mat vertex = vertexMap(depth, cam);
  const cv::Mat fast = computeNormals(vertex, p);
  int defined = 0, compared = 0;
  for (int v = 0; v < depth.rows; ++v) {
    for (int u = 0; u < depth.cols; ++u) {
      const cv::Vec3f f = fast.at<cv::Vec3f>(v, u);
      const bool border = u == 0 || v == 0 || u + 1 == depth.cols || v + 1 == depth.rows;
      if (border) {
        EXPECT_EQ(f, cv::Vec3f(0, 0, 0)) << u << "," << v;
        continue;
      }
      const auto X = [&](int uu, int vv) {
        const cv::Vec3f x = vertex.at<cv::Vec3f>(vv, uu);
        return Eigen::Vector3d(x[0], x[1], x[2]);
      };
      const Eigen::Vector3d c = X(u, v), l = X(u - 1, v), r = X(u + 1, v), t = X(u, v - 1), b = X(u, v + 1);
      const double d = c.z() - 0.4, jump = 2 * p.edge_jump_sigmas * (p.noise_sigma_a_m + p.noise_sigma_b_per_m * d * d);
      // Pixels whose jump test is within float rounding of its threshold
      // may go either way.
      const double margin = 1e-5;
      if (std::abs(std::abs(l.z() - r.z()) - jump) < margin || std::abs(std::abs(t.z() - b.z()) - jump) < margin) {
        continue;
      }
      Eigen::Vector3d n = (r - l).cross(b - t);
      const bool ok = c.z() > 0 && l.z() > 0 && r.z() > 0 && t.z() > 0 && b.z() > 0 &&
                      std::abs(l.z() - r.z()) <= jump && std::abs(t.z() - b.z()) <= jump && n.norm() > 0;
      ++compared;
      if (!ok) {
        EXPECT_EQ(f, cv::Vec3f(0, 0, 0)) << "no normal at " << u << "," << v;
        continue;
      }
      n.normalize();
      if (n.dot(c) > 0) n = -n;
      ++defined;
      EXPECT_LT((Eigen::Vector3d(f[0], f[1], f[2]) - n).norm(), 1e-5) << u << "," << v;
    }
  }
  // The test depth has holes (10 %), a step and noise: both cases occur.
  EXPECT_GT(defined, compared / 3);
  EXPECT_LT(defined, compared);
}

TEST(Preprocess, BilateralFilterKeepsTheStepAndReducesNoise) {
  const PreprocessParams p;
  const cv::Mat depth = testDepth();
  const cv::Mat out = bilateralDepth(depth, p);
  double in_sq = 0, out_sq = 0;
  int n = 0;
  for (int v = 3; v < depth.rows - 3; ++v) {
    for (int u = 3; u < depth.cols - 3; ++u) {
      if (depth.at<float>(v, u) <= 0) continue;
      const double truth = 1.0 + 0.004 * u + 0.002 * v + (u > 40 ? 0.3 : 0.0);
      in_sq += std::pow(depth.at<float>(v, u) - truth, 2);
      out_sq += std::pow(out.at<float>(v, u) - truth, 2);
      ++n;
      // Next to the step, nothing from the other side is mixed in.
      EXPECT_NEAR(out.at<float>(v, u), truth, 0.02) << u << "," << v;
    }
  }
  EXPECT_LT(std::sqrt(out_sq / n), 0.75 * std::sqrt(in_sq / n));  // 0.61 seen
}

}  // namespace
}  // namespace hxmap::alg
