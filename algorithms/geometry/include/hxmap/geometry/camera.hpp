// Pinhole camera model. Pixel (u, v) has its center at integer coordinates;
// the optical axis is +z, x right, y down (OpenCV convention).
#pragma once

#include <array>

#include <Eigen/Core>

namespace hxmap::alg {

struct PinholeCamera {
  double fx = 525.0, fy = 525.0, cx = 319.5, cy = 239.5;
  int width = 640, height = 480;
  /// Brown-Conrady k1, k2, p1, p2, k3 of the raw images; readers undistort
  /// images so that frames downstream are distortion free.
  std::array<double, 5> distortion{0, 0, 0, 0, 0};

  bool hasDistortion() const {
    for (double d : distortion) {
      if (d != 0.0) return true;
    }
    return false;
  }

  /// The camera of pyramid level `level` (each level halves the resolution;
  /// pixel centers stay consistent with 2x2 block averaging).
  PinholeCamera level(int level) const {
    PinholeCamera c = *this;
    for (int i = 0; i < level; ++i) {
      c.fx *= 0.5;
      c.fy *= 0.5;
      c.cx = (c.cx + 0.5) * 0.5 - 0.5;
      c.cy = (c.cy + 0.5) * 0.5 - 0.5;
      c.width /= 2;
      c.height /= 2;
    }
    c.distortion = {0, 0, 0, 0, 0};
    return c;
  }

  /// Camera-frame point to pixel; z must be > 0.
  Eigen::Vector2f project(const Eigen::Vector3f& p_cam) const {
    return {static_cast<float>(fx) * p_cam.x() / p_cam.z() + static_cast<float>(cx),
            static_cast<float>(fy) * p_cam.y() / p_cam.z() + static_cast<float>(cy)};
  }

  /// Pixel and depth along the optical axis (meters) to a camera-frame point.
  Eigen::Vector3f backproject(float u, float v, float z_m) const {
    return {(u - static_cast<float>(cx)) / static_cast<float>(fx) * z_m,
            (v - static_cast<float>(cy)) / static_cast<float>(fy) * z_m, z_m};
  }

  bool inside(float u, float v) const {
    return u >= 0.0f && v >= 0.0f && u <= static_cast<float>(width - 1) && v <= static_cast<float>(height - 1);
  }
};

}  // namespace hxmap::alg
