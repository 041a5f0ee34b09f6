// Pairing a color and a depth stream by time, and turning a pair into the
// registered RgbdFrame the pipeline takes.
//
// StreamSync: both streams arrive in stamp order, each possibly with
// jitter, drops and its own rate. A color frame is paired with the depth
// frame nearest in time once that is decided (a depth frame at or after
// its stamp has arrived: later ones can only be farther), if the gap is at
// most max_gap_s; otherwise the color frame is dropped. A depth frame is
// used at most once; depth frames older than any color frame they could
// still pair with are dropped. Every drop is counted by reason. Bounded
// queues: a stalled stream cannot grow memory.
//
// FrameAssembler: raw depth to meters, depth undistorted (nearest, no
// mixing across edges) and reprojected into the color camera with the
// calibrated extrinsics unless the device registers in hardware, color
// undistorted: frames leave distortion free in the color camera.
//
// Thread safety: none; one StreamSync / FrameAssembler per sensor thread.
#pragma once

#include <cstdint>
#include <deque>
#include <optional>
#include <string>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "hxmap/core/expected.hpp"
#include "hxmap/core/frame.hpp"
#include "hxmap/geometry/camera.hpp"

namespace hxmap::drv {

struct ColorImage {
  int64_t stamp_ns = 0;
  uint64_t seq = 0;
  cv::Mat rgb;  ///< CV_8UC3, R G B
};

struct DepthImage {
  int64_t stamp_ns = 0;
  uint64_t seq = 0;
  cv::Mat raw;  ///< CV_16UC1 in device units (depth_scale per meter), 0 = no measurement
};

/// Calibration of a color + depth camera pair.
struct RigCalibration {
  alg::PinholeCamera color;
  alg::PinholeCamera depth;
  /// Depth-camera points into the color camera's frame.
  Eigen::Isometry3d T_color_depth = Eigen::Isometry3d::Identity();
  double depth_scale = 1000.0;  ///< raw depth units per meter
  /// The device already registers depth to color (same size and camera).
  bool registered = false;
  double max_depth_m = 0;       ///< deeper raw values become 0; 0 = no limit
};

struct SyncStats {
  uint64_t pairs = 0;
  uint64_t color_dropped = 0;        ///< no depth frame within max_gap_s (or queue overflow)
  uint64_t depth_dropped = 0;        ///< never the nearest to any color frame
  uint64_t out_of_order = 0;         ///< stamps going backwards, dropped
  double max_gap_paired_s = 0;
};

struct SyncedPair {
  ColorImage color;
  DepthImage depth;
};

class StreamSync {
 public:
  explicit StreamSync(double max_gap_s, size_t max_queue = 8);

  void pushColor(ColorImage color);
  void pushDepth(DepthImage depth);
  /// The next decided pair, oldest first; nothing when undecided.
  std::optional<SyncedPair> pop();
  const SyncStats& stats() const { return stats_; }
  size_t queuedColor() const { return color_.size(); }
  size_t queuedDepth() const { return depth_.size(); }

 private:
  int64_t max_gap_ns_;
  size_t max_queue_;
  std::deque<ColorImage> color_;
  std::deque<DepthImage> depth_;
  int64_t last_color_ns_ = INT64_MIN, last_depth_ns_ = INT64_MIN;
  SyncStats stats_;
};

/// Raw 16-bit depth to meters (CV_32F, 0 where raw is 0 or deeper than max_depth_m > 0).
cv::Mat depthToMeters(const cv::Mat& raw, double depth_scale, double max_depth_m = 0);

/// Depth in meters from an undistorted depth camera reprojected into an
/// undistorted color camera (`color` sets the output size): each pixel's
/// point is moved by T_color_depth and projected; the nearest surface wins
/// a pixel; pixels nothing lands on stay 0.
cv::Mat registerDepth(const cv::Mat& depth_m, const alg::PinholeCamera& depth, const alg::PinholeCamera& color,
                      const Eigen::Isometry3d& T_color_depth);

class FrameAssembler {
 public:
  /// Checks the calibration (sizes, focal lengths, scale); errors name the key.
  static Expected<FrameAssembler> create(const RigCalibration& calibration);
  /// The camera of the frames made (the color camera without distortion).
  const alg::PinholeCamera& camera() const { return camera_; }
  /// A registered frame stamped with the color image's time. Errors name
  /// the stream and what is wrong (size, type).
  Expected<RgbdFrame> assemble(const ColorImage& color, const DepthImage& depth, uint64_t seq) const;

 private:
  RigCalibration cal_;
  alg::PinholeCamera camera_, depth_camera_;
  cv::Mat color_map_x_, color_map_y_, depth_map_x_, depth_map_y_;  ///< empty when no distortion
};

}  // namespace hxmap::drv
