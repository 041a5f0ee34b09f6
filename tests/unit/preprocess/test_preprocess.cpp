#include <gtest/gtest.h>

#include <cmath>
#include <random>

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
