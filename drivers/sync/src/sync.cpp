#include "hxmap/sync/sync.hpp"

#include <cmath>
#include <limits>

#include <fmt/format.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace hxmap::drv {

StreamSync::StreamSync(double max_gap_s, size_t max_queue)
    : max_gap_ns_(static_cast<int64_t>(max_gap_s * 1e9)), max_queue_(std::max<size_t>(max_queue, 1)) {}

void StreamSync::pushColor(ColorImage color) {
  if (color.stamp_ns <= last_color_ns_) {
    ++stats_.out_of_order;
    return;
  }
  last_color_ns_ = color.stamp_ns;
  color_.push_back(std::move(color));
  while (color_.size() > max_queue_) {  // the depth stream stalled
    color_.pop_front();
    ++stats_.color_dropped;
  }
}

void StreamSync::pushDepth(DepthImage depth) {
  if (depth.stamp_ns <= last_depth_ns_) {
    ++stats_.out_of_order;
    return;
  }
  last_depth_ns_ = depth.stamp_ns;
  depth_.push_back(std::move(depth));
  while (depth_.size() > max_queue_) {  // the color stream stalled
    depth_.pop_front();
    ++stats_.depth_dropped;
  }
}

std::optional<SyncedPair> StreamSync::pop() {
  while (!color_.empty()) {
    const int64_t c = color_.front().stamp_ns;
    // Depth too old for this color frame is too old for every later one.
    while (!depth_.empty() && depth_.front().stamp_ns < c - max_gap_ns_) {
      depth_.pop_front();
      ++stats_.depth_dropped;
    }
    if (depth_.empty() || depth_.back().stamp_ns < c) {
      // Undecided: a nearer depth frame may still come. Unless a later color
      // frame shows this one cannot pair (all depth that could come is past
      // its window).
      if (color_.size() > 1 && depth_.empty() && last_depth_ns_ > c + max_gap_ns_) {
        color_.pop_front();
        ++stats_.color_dropped;
        continue;
      }
      return std::nullopt;
    }
    // Nearest depth frame (the queue is in stamp order).
    size_t best = 0;
    int64_t best_gap = std::numeric_limits<int64_t>::max();
    for (size_t i = 0; i < depth_.size(); ++i) {
      const int64_t gap = std::llabs(depth_[i].stamp_ns - c);
      if (gap < best_gap) {
        best_gap = gap;
        best = i;
      }
      if (depth_[i].stamp_ns >= c) break;
    }
    if (best_gap > max_gap_ns_) {
      color_.pop_front();
      ++stats_.color_dropped;
      continue;
    }
    SyncedPair pair{std::move(color_.front()), std::move(depth_[best])};
    color_.pop_front();
    for (size_t i = 0; i < best; ++i) ++stats_.depth_dropped;
    depth_.erase(depth_.begin(), depth_.begin() + static_cast<std::ptrdiff_t>(best) + 1);
    ++stats_.pairs;
    stats_.max_gap_paired_s = std::max(stats_.max_gap_paired_s, static_cast<double>(best_gap) * 1e-9);
    return pair;
  }
  return std::nullopt;
}

cv::Mat depthToMeters(const cv::Mat& raw, double depth_scale, double max_depth_m) {
  cv::Mat out(raw.size(), CV_32F);
  const float inv = static_cast<float>(1.0 / depth_scale);
  const float max_d = max_depth_m > 0 ? static_cast<float>(max_depth_m) : std::numeric_limits<float>::infinity();
  for (int v = 0; v < raw.rows; ++v) {
    const uint16_t* in = raw.ptr<uint16_t>(v);
    float* o = out.ptr<float>(v);
    for (int u = 0; u < raw.cols; ++u) {
      const float d = static_cast<float>(in[u]) * inv;
      o[u] = d <= max_d ? d : 0.0f;
    }
  }
  return out;
}

cv::Mat registerDepth(const cv::Mat& depth_m, const alg::PinholeCamera& depth, const alg::PinholeCamera& color,
                      const Eigen::Isometry3d& T_color_depth) {
  cv::Mat out(color.height, color.width, CV_32F, cv::Scalar(0));
  const Eigen::Matrix3f R = T_color_depth.linear().cast<float>();
  const Eigen::Vector3f t = T_color_depth.translation().cast<float>();
  const float dfx = static_cast<float>(1.0 / depth.fx), dfy = static_cast<float>(1.0 / depth.fy);
  const float dcx = static_cast<float>(depth.cx), dcy = static_cast<float>(depth.cy);
  const float fx = static_cast<float>(color.fx), fy = static_cast<float>(color.fy);
  const float cx = static_cast<float>(color.cx), cy = static_cast<float>(color.cy);
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* row = depth_m.ptr<float>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      const float z = row[u];
      if (!(z > 0.0f) || !std::isfinite(z)) continue;
      const Eigen::Vector3f p = R * Eigen::Vector3f((static_cast<float>(u) - dcx) * dfx * z, (static_cast<float>(v) - dcy) * dfy * z, z) + t;
      if (p.z() <= 0.0f) continue;
      const int uc = static_cast<int>(std::lround(fx * p.x() / p.z() + cx));
      const int vc = static_cast<int>(std::lround(fy * p.y() / p.z() + cy));
      if (uc < 0 || vc < 0 || uc >= color.width || vc >= color.height) continue;
      float& o = out.at<float>(vc, uc);
      if (o == 0.0f || p.z() < o) o = p.z();
    }
  }
  return out;
}

namespace {

void undistortMaps(const alg::PinholeCamera& cam, cv::Mat& map_x, cv::Mat& map_y) {
  if (!cam.hasDistortion()) return;
  const cv::Matx33d K(cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
  const cv::Mat dist = (cv::Mat_<double>(1, 5) << cam.distortion[0], cam.distortion[1], cam.distortion[2],
                        cam.distortion[3], cam.distortion[4]);
  cv::initUndistortRectifyMap(K, dist, cv::noArray(), K, cv::Size(cam.width, cam.height), CV_32FC1, map_x, map_y);
}

Status checkCamera(const alg::PinholeCamera& c, const char* which) {
  if (c.width < 8 || c.height < 8) return Error{fmt::format("calibration: {} camera size {}x{} is too small", which, c.width, c.height)};
  if (!(c.fx > 0) || !(c.fy > 0) || !std::isfinite(c.fx) || !std::isfinite(c.fy)) {
    return Error{fmt::format("calibration: {} camera focal lengths fx {} fy {} must be positive", which, c.fx, c.fy)};
  }
  return Status::ok();
}

}  // namespace

Expected<FrameAssembler> FrameAssembler::create(const RigCalibration& cal) {
  if (auto s = checkCamera(cal.color, "color"); !s) return Error{s.message()};
  if (!cal.registered) {
    if (auto s = checkCamera(cal.depth, "depth"); !s) return Error{s.message()};
  }
  if (!(cal.depth_scale > 0) || !std::isfinite(cal.depth_scale)) {
    return Error{fmt::format("calibration: depth_scale {} must be positive (raw units per meter)", cal.depth_scale)};
  }
  if (!cal.T_color_depth.matrix().allFinite()) return Error{"calibration: the depth-to-color extrinsics are not finite"};
  FrameAssembler a;
  a.cal_ = cal;
  a.camera_ = cal.color;
  a.camera_.distortion = {0, 0, 0, 0, 0};
  a.depth_camera_ = cal.registered ? cal.color : cal.depth;
  undistortMaps(cal.color, a.color_map_x_, a.color_map_y_);
  undistortMaps(a.depth_camera_, a.depth_map_x_, a.depth_map_y_);
  a.depth_camera_.distortion = {0, 0, 0, 0, 0};
  return a;
}

Expected<RgbdFrame> FrameAssembler::assemble(const ColorImage& color, const DepthImage& depth, uint64_t seq) const {
  if (color.rgb.type() != CV_8UC3 || color.rgb.cols != camera_.width || color.rgb.rows != camera_.height) {
    return Error{fmt::format("color frame {}: {}x{} type {}, calibration expects {}x{} 8-bit RGB", color.seq, color.rgb.cols,
                             color.rgb.rows, color.rgb.type(), camera_.width, camera_.height)};
  }
  if (depth.raw.type() != CV_16UC1 || depth.raw.cols != depth_camera_.width || depth.raw.rows != depth_camera_.height) {
    return Error{fmt::format("depth frame {}: {}x{} type {}, calibration expects {}x{} 16-bit", depth.seq, depth.raw.cols,
                             depth.raw.rows, depth.raw.type(), depth_camera_.width, depth_camera_.height)};
  }
  RgbdFrame f;
  f.stamp_ns = color.stamp_ns;
  f.depth_stamp_ns = depth.stamp_ns;
  f.seq = seq;
  if (color_map_x_.empty()) {
    f.rgb = color.rgb.clone();
  } else {
    cv::remap(color.rgb, f.rgb, color_map_x_, color_map_y_, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  }
  cv::Mat d = depthToMeters(depth.raw, cal_.depth_scale, cal_.max_depth_m);
  if (!depth_map_x_.empty()) {
    cv::Mat u;
    cv::remap(d, u, depth_map_x_, depth_map_y_, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
    d = u;
  }
  f.depth = cal_.registered ? d : registerDepth(d, depth_camera_, camera_, cal_.T_color_depth);
  return f;
}

}  // namespace hxmap::drv
