// The frame every source yields (datasets, cameras, synthetic scenes).
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

namespace hxmap {

/// One registered color + depth pair. `depth` is CV_32FC1 in meters with 0 for
/// invalid pixels; `rgb` is CV_8UC3 in R,G,B order, same size as `depth`.
struct RgbdFrame {
  int64_t stamp_ns = 0;  ///< capture time of the color image
  uint64_t seq = 0;      ///< index in the source, 0-based, gaps mean drops
  cv::Mat rgb;
  cv::Mat depth;
  /// Capture time of the depth image when the sensor does not synchronize
  /// the two (Kinect v1: up to half a frame apart); 0 = stamp_ns.
  int64_t depth_stamp_ns = 0;
};

/// A pose with a timestamp: T_world_cam maps camera points into the world.
struct StampedPose {
  int64_t stamp_ns = 0;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
};

using Trajectory = std::vector<StampedPose>;

}  // namespace hxmap
