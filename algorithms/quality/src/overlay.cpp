// Images of the indicators for people: per pixel the score of the block its
// depth lands in, as a heat map over the keyframe, with the ROI boxes drawn.
#include <algorithm>
#include <cmath>
#include <unordered_map>

#include <opencv2/imgproc.hpp>

#include "hxmap/quality/quality.hpp"

namespace hxmap::alg {

cv::Mat indicatorImage(const std::vector<BlockScore>& scores, const FrameLevel& frame,
                       const Eigen::Isometry3f& T_world_cam, float block_size_m, int indicator) {
  std::unordered_map<uint64_t, float> value;
  value.reserve(scores.size());
  for (const BlockScore& s : scores) {
    value[packBlockKey(s.key)] = indicator >= 0 && indicator < kIndicatorCount ? s.normalized[indicator] : s.priority;
  }
  // S combines the normalized indicators (params.priority_rule); shown relative to its maximum.
  float scale = 1.0f;
  if (indicator < 0 || indicator >= kIndicatorCount) {
    float top = 0;
    for (const BlockScore& s : scores) top = std::max(top, s.priority);
    scale = top > 0 ? 1.0f / top : 1.0f;
  }
  cv::Mat out(frame.depth.size(), CV_32F, cv::Scalar(-1.0f));
  const float inv_bs = 1.0f / block_size_m;
  for (int v = 0; v < frame.depth.rows; ++v) {
    const float* d = frame.depth.ptr<float>(v);
    float* o = out.ptr<float>(v);
    for (int u = 0; u < frame.depth.cols; ++u) {
      if (!(d[u] > 0.0f) || !std::isfinite(d[u])) continue;
      const Eigen::Vector3f q = (T_world_cam * frame.camera.backproject(static_cast<float>(u), static_cast<float>(v), d[u])) * inv_bs;
      auto it = value.find(packBlockKey(BlockKey(floorToInt(q.x()), floorToInt(q.y()), floorToInt(q.z()))));
      if (it != value.end()) o[u] = std::clamp(it->second * scale, 0.0f, 1.0f);
    }
  }
  return out;
}

cv::Mat overlayHeatmap(const cv::Mat& rgb, const cv::Mat& values) {
  cv::Mat v8(values.size(), CV_8U), valid(values.size(), CV_8U);
  for (int v = 0; v < values.rows; ++v) {
    const float* x = values.ptr<float>(v);
    for (int u = 0; u < values.cols; ++u) {
      v8.ptr<uint8_t>(v)[u] = static_cast<uint8_t>(std::clamp(x[u], 0.0f, 1.0f) * 255.0f + 0.5f);
      valid.ptr<uint8_t>(v)[u] = x[u] >= 0.0f ? 255 : 0;
    }
  }
  cv::Mat heat;
  cv::applyColorMap(v8, heat, cv::COLORMAP_JET);  // BGR
  cv::cvtColor(heat, heat, cv::COLOR_BGR2RGB);
  cv::resize(heat, heat, rgb.size(), 0, 0, cv::INTER_NEAREST);
  cv::resize(valid, valid, rgb.size(), 0, 0, cv::INTER_NEAREST);
  cv::Mat gray, out;
  cv::cvtColor(rgb, gray, cv::COLOR_RGB2GRAY);
  cv::cvtColor(gray, out, cv::COLOR_GRAY2RGB);
  cv::Mat blended;
  cv::addWeighted(out, 0.45, heat, 0.55, 0.0, blended);
  blended.copyTo(out, valid);
  return out;
}

void drawRoiBoxes(cv::Mat& image, const std::vector<Roi>& rois, const PinholeCamera& camera,
                  const Eigen::Isometry3f& T_world_cam) {
  const Eigen::Isometry3f T_cam_world = T_world_cam.inverse();
  const float near = 0.05f;
  const int thickness = std::max(1, image.cols / 320);
  for (const Roi& roi : rois) {
    Eigen::Vector3f c[8];
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3f w((i & 1) ? roi.box_world.max().x() : roi.box_world.min().x(),
                              (i & 2) ? roi.box_world.max().y() : roi.box_world.min().y(),
                              (i & 4) ? roi.box_world.max().z() : roi.box_world.min().z());
      c[i] = T_cam_world * w;
    }
    for (int a = 0; a < 8; ++a) {
      for (int bit : {1, 2, 4}) {
        if (a & bit) continue;
        Eigen::Vector3f p = c[a], q = c[a | bit];
        if (p.z() < near && q.z() < near) continue;
        // Clip the edge at the near plane.
        if (p.z() < near) p = p + (q - p) * ((near - p.z()) / (q.z() - p.z()));
        if (q.z() < near) q = q + (p - q) * ((near - q.z()) / (p.z() - q.z()));
        const Eigen::Vector2f a2 = camera.project(p), b2 = camera.project(q);
        cv::Point2f pa(a2.x(), a2.y()), pb(b2.x(), b2.y());
        // Far off-screen coordinates overflow cv::line's fixed point: clip to a margin.
        cv::Rect2f bounds(-4.0f * image.cols, -4.0f * image.rows, 9.0f * image.cols, 9.0f * image.rows);
        if (!bounds.contains(pa) || !bounds.contains(pb)) {
          cv::Point ia(pa), ib(pb);
          if (!cv::clipLine(cv::Rect(bounds), ia, ib)) continue;
          pa = ia;
          pb = ib;
        }
        cv::line(image, pa, pb, cv::Scalar(255, 230, 0), thickness, cv::LINE_AA);
      }
    }
  }
}

}  // namespace hxmap::alg
