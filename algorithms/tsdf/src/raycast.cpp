#include "hxmap/tsdf/raycast.hpp"

#include <atomic>
#include <cmath>

namespace hxmap::alg {

namespace {

// Distance along the ray to the exit of the block containing p.
float blockExit(const TsdfMap& map, const BlockKey& key, const Eigen::Vector3f& o, const Eigen::Vector3f& inv_dir) {
  const Eigen::Vector3f lo = key.cast<float>() * map.blockSize();
  const Eigen::Vector3f hi = lo + Eigen::Vector3f::Constant(map.blockSize());
  const Eigen::Vector3f t0 = (lo - o).cwiseProduct(inv_dir), t1 = (hi - o).cwiseProduct(inv_dir);
  return t0.cwiseMax(t1).minCoeff();
}

}  // namespace

ModelView raycast(const TsdfMap& map, const PinholeCamera& cam, const Eigen::Isometry3f& T_world_cam,
                  const RaycastParams& params, bool with_color, const ParallelFor& parallel) {
  ModelView view;
  view.camera = cam;
  view.T_world_cam = T_world_cam;
  view.depth = cv::Mat(cam.height, cam.width, CV_32F, cv::Scalar(0));
  view.vertex_world = cv::Mat(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  view.normal_world = cv::Mat(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  if (with_color) view.rgb = cv::Mat(cam.height, cam.width, CV_8UC3, cv::Scalar(0, 0, 0));
  const float vs = map.voxelSize(), mu = map.truncation();
  const float min_w = static_cast<float>(params.min_weight);
  const float step_factor = static_cast<float>(params.step_factor);
  const Eigen::Vector3f origin = T_world_cam.translation();
  const Eigen::Matrix3f R = T_world_cam.linear();
  std::atomic<int> valid{0};
  parallel(static_cast<size_t>(cam.height), [&](size_t v0, size_t v1) {
    int local_valid = 0;
    for (int v = static_cast<int>(v0); v < static_cast<int>(v1); ++v) {
      float* drow = view.depth.ptr<float>(v);
      auto* vrow = view.vertex_world.ptr<cv::Vec3f>(v);
      for (int u = 0; u < cam.width; ++u) {
        const Eigen::Vector3f ray_cam = cam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
        const float len = ray_cam.norm();
        const Eigen::Vector3f dir = R * ray_cam / len;
        const Eigen::Vector3f inv_dir = dir.cwiseInverse();
        float t = static_cast<float>(params.min_depth_m) * len;
        const float t_max = static_cast<float>(params.max_depth_m) * len;
        float prev_t = -1, prev_sdf = 0;
        float hit = -1;
        int guard = 0;
        while (t < t_max && ++guard < 4096) {
          const Eigen::Vector3f p = origin + t * dir;
          const BlockKey key = map.blockOf(p);
          if (map.find(key) < 0) {
            t = std::max(t + 0.5f * vs, blockExit(map, key, origin, inv_dir) + 1e-4f);
            prev_t = -1;
            continue;
          }
          float sdf = 0;
          if (!map.sample(p, min_w, sdf)) {
            t += 0.5f * vs;
            prev_t = -1;
            continue;
          }
          if (prev_t >= 0 && prev_sdf > 0 && sdf <= 0) {
            float th = prev_t + (t - prev_t) * prev_sdf / (prev_sdf - sdf);
            // One secant refinement on the interpolated point.
            float s_mid = 0;
            if (map.sample(origin + th * dir, min_w, s_mid)) {
              if (s_mid > 0 && sdf < 0) {
                th = th + (t - th) * s_mid / (s_mid - sdf);
              } else if (s_mid < 0 && prev_sdf > 0) {
                th = prev_t + (th - prev_t) * prev_sdf / (prev_sdf - s_mid);
              }
            }
            hit = th;
            break;
          }
          prev_t = t;
          prev_sdf = sdf;
          t += std::max(0.5f * vs, step_factor * std::min(std::abs(sdf), mu));
        }
        if (hit < 0) continue;
        const Eigen::Vector3f p = origin + hit * dir;
        drow[u] = hit / len;
        vrow[u] = cv::Vec3f(p.x(), p.y(), p.z());
        ++local_valid;
        if (with_color) {
          Eigen::Vector3f c;
          if (map.sampleColor(p, c)) {
            view.rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(static_cast<uint8_t>(std::lround(c.x())),
                                                     static_cast<uint8_t>(std::lround(c.y())),
                                                     static_cast<uint8_t>(std::lround(c.z())));
          }
        }
      }
    }
    valid += local_valid;
  });
  view.valid_pixels = valid;
  // Normals from neighbouring vertices; rejected across jumps of more than
  // a few voxels (a silhouette, not a surface).
  const float max_jump = 4.0f * vs;
  for (int v = 1; v + 1 < cam.height; ++v) {
    const float* d0 = view.depth.ptr<float>(v - 1);
    const float* d1 = view.depth.ptr<float>(v);
    const float* d2 = view.depth.ptr<float>(v + 1);
    const auto* up = view.vertex_world.ptr<cv::Vec3f>(v - 1);
    const auto* mid = view.vertex_world.ptr<cv::Vec3f>(v);
    const auto* down = view.vertex_world.ptr<cv::Vec3f>(v + 1);
    auto* out = view.normal_world.ptr<cv::Vec3f>(v);
    for (int u = 1; u + 1 < cam.width; ++u) {
      if (d1[u] <= 0 || d1[u - 1] <= 0 || d1[u + 1] <= 0 || d0[u] <= 0 || d2[u] <= 0) continue;
      if (std::abs(d1[u + 1] - d1[u - 1]) > max_jump * 2 || std::abs(d2[u] - d0[u]) > max_jump * 2) continue;
      cv::Vec3f n = (mid[u + 1] - mid[u - 1]).cross(down[u] - up[u]);
      const float l = std::sqrt(n.dot(n));
      if (!(l > 0)) continue;
      n *= 1.0f / l;
      const cv::Vec3f to_cam(origin.x() - mid[u][0], origin.y() - mid[u][1], origin.z() - mid[u][2]);
      if (n.dot(to_cam) < 0) n = -n;
      out[u] = n;
    }
  }
  return view;
}

ModelView subsampleView(const ModelView& view) {
  ModelView out;
  out.camera = view.camera.level(1);
  out.T_world_cam = view.T_world_cam;
  const int W = out.camera.width, H = out.camera.height;
  out.depth = cv::Mat(H, W, CV_32F);
  out.vertex_world = cv::Mat(H, W, CV_32FC3);
  out.normal_world = cv::Mat(H, W, CV_32FC3);
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      // The level-1 pixel center (u, v) lies between fine pixels 2u and 2u+1;
      // take the fine pixel 2u, 2v (half a fine pixel off, well below ICP's gates).
      out.depth.at<float>(v, u) = view.depth.at<float>(2 * v, 2 * u);
      out.vertex_world.at<cv::Vec3f>(v, u) = view.vertex_world.at<cv::Vec3f>(2 * v, 2 * u);
      out.normal_world.at<cv::Vec3f>(v, u) = view.normal_world.at<cv::Vec3f>(2 * v, 2 * u);
      out.valid_pixels += out.depth.at<float>(v, u) > 0;
    }
  }
  return out;
}

}  // namespace hxmap::alg
