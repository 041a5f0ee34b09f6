#include "hxmap/tsdf/raycast.hpp"

#include <atomic>
#include <cmath>
#include <limits>

namespace hxmap::alg {

namespace {

// Distance along the ray to the exit of the block containing p.
float blockExit(const TsdfMap& map, const BlockKey& key, const Eigen::Vector3f& o, const Eigen::Vector3f& inv_dir) {
  const Eigen::Vector3f lo = key.cast<float>() * map.blockSize();
  const Eigen::Vector3f hi = lo + Eigen::Vector3f::Constant(map.blockSize());
  const Eigen::Vector3f t0 = (lo - o).cwiseProduct(inv_dir), t1 = (hi - o).cwiseProduct(inv_dir);
  return t0.cwiseMax(t1).minCoeff();
}

constexpr int kTile = 16;  // pixels per side of a depth-bounds tile

// Per tile of kTile x kTile pixels, the depth range [near, far] covered by
// allocated blocks (their corners projected), so rays start next to the
// surface instead of at the camera. Tiles no block projects into get
// near > far and are skipped.
void tileBounds(const TsdfMap& map, const PinholeCamera& cam, const Eigen::Isometry3f& T_cam_world, float max_z,
                std::vector<float>& near, std::vector<float>& far, int tw, int th) {
  near.assign(static_cast<size_t>(tw * th), std::numeric_limits<float>::max());
  far.assign(static_cast<size_t>(tw * th), 0.0f);
  const float bs = map.blockSize();
  for (size_t b = 0; b < map.blockCount(); ++b) {
    const Eigen::Vector3f lo = map.key(b).cast<float>() * bs;
    float zmin = std::numeric_limits<float>::max(), zmax = 0;
    float umin = 1e9f, umax = -1e9f, vmin = 1e9f, vmax = -1e9f;
    bool behind = false;
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3f p = T_cam_world * (lo + bs * Eigen::Vector3f(c & 1, (c >> 1) & 1, (c >> 2) & 1));
      if (p.z() < 0.05f) {
        behind = true;
        break;
      }
      zmin = std::min(zmin, p.z());
      zmax = std::max(zmax, p.z());
      const Eigen::Vector2f uv = cam.project(p);
      umin = std::min(umin, uv.x());
      umax = std::max(umax, uv.x());
      vmin = std::min(vmin, uv.y());
      vmax = std::max(vmax, uv.y());
    }
    if (zmin > max_z) continue;
    if (behind) {  // straddles the camera plane: the whole image from the camera on
      zmin = 0.0f;
      umin = vmin = 0.0f;
      umax = static_cast<float>(cam.width);
      vmax = static_cast<float>(cam.height);
      zmax = max_z;
    }
    const int t0x = std::max(0, static_cast<int>(umin) / kTile), t1x = std::min(tw - 1, static_cast<int>(umax) / kTile);
    const int t0y = std::max(0, static_cast<int>(vmin) / kTile), t1y = std::min(th - 1, static_cast<int>(vmax) / kTile);
    if (umax < 0 || vmax < 0) continue;
    for (int ty = t0y; ty <= t1y; ++ty) {
      for (int tx = t0x; tx <= t1x; ++tx) {
        const size_t i = static_cast<size_t>(ty * tw + tx);
        near[i] = std::min(near[i], zmin);
        far[i] = std::max(far[i], zmax);
      }
    }
  }
}

// The surface between ta (sdf sa > 0) and tb (sb <= 0): the secant, then
// one more trilinear sample and the secant on the side that brackets.
float refineCrossing(BlockCache& cache, const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float min_w,
                     float ta, float sa, float tb, float sb) {
  float th = ta + (tb - ta) * sa / (sa - sb);
  float s_mid = 0;
  if (cache.sample(origin + th * dir, min_w, s_mid)) {
    if (s_mid > 0 && sb < 0) {
      th = th + (tb - th) * s_mid / (s_mid - sb);
    } else if (s_mid < 0 && sa > 0) {
      th = ta + (th - ta) * sa / (sa - s_mid);
    }
  }
  return th;
}

// One pixel's ray in the world: direction, its inverse, and its length per
// unit of depth (depth z along the optical axis is t / len along the ray).
struct Ray {
  Eigen::Vector3f origin, dir, inv_dir;
  float len = 1;
};

struct MarchParams {
  float vs = 0, mu = 0, min_w = 0, step_factor = 1;
};

// The surface near a predicted depth zh. DESIGN: the prediction is the depth
// just fused at (nearly) this pose, so the surface is almost always within
// a voxel of it: trilinear samples 1.5 voxels either side (the truncated
// SDF is linear there) bracket it, three samples and no march. (A one-voxel
// bracket saved 0.6 ms per frame but cost tracking accuracy.) `sampled` is
// false where a sample has no trilinear neighbourhood (the edge of the
// observed surface, where a march would not find a bracketed crossing
// either). Returns the hit's t along the ray, or -1.
float hitNearDepth(BlockCache& cache, const Ray& ray, const MarchParams& mp, float zh, float t_min, bool& sampled) {
  const float ta = (zh - 1.5f * mp.vs) * ray.len, tb = (zh + 1.5f * mp.vs) * ray.len;
  float sa = 0, sb = 0;
  sampled = ta > t_min && cache.sample(ray.origin + ta * ray.dir, mp.min_w, sa) &&
            cache.sample(ray.origin + tb * ray.dir, mp.min_w, sb);
  if (sampled && sa > 0 && sb <= 0) return refineCrossing(cache, ray.origin, ray.dir, mp.min_w, ta, sa, tb, sb);
  return -1;
}

// March from t to t_end: nearest-voxel samples, steps of the SDF, block
// skipping, then the crossing refined on trilinear samples. `from_hint`: t
// is a predicted surface's band; should its first sample lie behind a
// surface already, the march starts over at t_restart. Returns the hit's t,
// or -1.
float march(const TsdfMap& map, BlockCache& cache, const Ray& ray, const MarchParams& mp, float t, float t_end,
            bool from_hint, float t_restart) {
  const float vs = mp.vs;
  float prev_t = -1, prev_sdf = 0;
  int guard = 0;
  while (t < t_end && ++guard < 4096) {
    const Eigen::Vector3f p = ray.origin + t * ray.dir;
    const Eigen::Vector3i g = map.voxelOf(p);
    int vi = 0;
    const VoxelBlock* blk = cache.blockOfVoxel(g, vi);
    if (blk == nullptr) {
      const BlockKey key(g.x() >> 3, g.y() >> 3, g.z() >> 3);
      t = std::max(t + 0.5f * vs, blockExit(map, key, ray.origin, ray.inv_dir) + 1e-4f);
      prev_t = -1;
      continue;
    }
    if (blk->geo[vi].weight <= mp.min_w) {
      t += vs;
      prev_t = -1;
      continue;
    }
    const float sdf = blk->geo[vi].sdf_m;
    if (from_hint) {
      from_hint = false;
      if (sdf < 0) {  // started behind a surface
        t = t_restart;
        prev_t = -1;
        continue;
      }
    }
    if (prev_t >= 0 && prev_sdf > 0 && sdf <= 0) {
      // Crossing between prev_t and t (nearest-voxel values). Trilinear
      // samples at both ends; where they do not bracket the surface (it may
      // lie up to a voxel outside), move the ends outwards in half-voxel
      // steps.
      float ta = prev_t, tb = t, sa = 0, sb = 0;
      bool ok_a = cache.sample(ray.origin + ta * ray.dir, mp.min_w, sa);
      for (int k = 0; k < 3 && ok_a && sa <= 0; ++k) {
        ta -= 0.5f * vs;
        ok_a = cache.sample(ray.origin + ta * ray.dir, mp.min_w, sa);
      }
      bool ok_b = cache.sample(ray.origin + tb * ray.dir, mp.min_w, sb);
      for (int k = 0; k < 3 && ok_b && sb > 0; ++k) {
        tb += 0.5f * vs;
        ok_b = cache.sample(ray.origin + tb * ray.dir, mp.min_w, sb);
      }
      // No trilinear bracket (the edge of the observed surface, where
      // neighbours are missing): no hit rather than an imprecise one.
      if (!(ok_a && ok_b && sa > 0 && sb <= 0)) return -1;
      return refineCrossing(cache, ray.origin, ray.dir, mp.min_w, ta, sa, tb, sb);
    }
    prev_t = t;
    prev_sdf = sdf;
    t += std::max(0.5f * vs, mp.step_factor * (std::min(std::abs(sdf), mp.mu) - 0.5f * vs));
  }
  return -1;
}

// Normals from neighbouring vertices, facing the camera; none across jumps
// of more than a few voxels (a silhouette, not a surface).
void normalsFromVertices(ModelView& view, const Eigen::Vector3f& origin, float vs) {
  const int width = view.depth.cols, height = view.depth.rows;
  const float max_jump = 4.0f * vs;
  for (int v = 1; v + 1 < height; ++v) {
    const float* d0 = view.depth.ptr<float>(v - 1);
    const float* d1 = view.depth.ptr<float>(v);
    const float* d2 = view.depth.ptr<float>(v + 1);
    const auto* up = view.vertex_world.ptr<cv::Vec3f>(v - 1);
    const auto* mid = view.vertex_world.ptr<cv::Vec3f>(v);
    const auto* down = view.vertex_world.ptr<cv::Vec3f>(v + 1);
    auto* out = view.normal_world.ptr<cv::Vec3f>(v);
    for (int u = 1; u + 1 < width; ++u) {
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
}

}  // namespace

ModelView raycast(const TsdfMap& map, const PinholeCamera& cam, const Eigen::Isometry3f& T_world_cam,
                  const RaycastParams& params, bool with_color, const ParallelFor& parallel,
                  const cv::Mat& depth_hint) {
  const bool hinted = depth_hint.type() == CV_32FC1 && depth_hint.cols == cam.width && depth_hint.rows == cam.height;
  ModelView view;
  view.camera = cam;
  view.T_world_cam = T_world_cam;
  view.depth = cv::Mat(cam.height, cam.width, CV_32F, cv::Scalar(0));
  view.vertex_world = cv::Mat(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  view.normal_world = cv::Mat(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  if (with_color) view.rgb = cv::Mat(cam.height, cam.width, CV_8UC3, cv::Scalar(0, 0, 0));
  MarchParams mp;
  mp.vs = map.voxelSize();
  mp.mu = map.truncation();
  mp.min_w = static_cast<float>(params.min_weight);
  mp.step_factor = static_cast<float>(params.step_factor);
  const float vs = mp.vs;
  const Eigen::Vector3f origin = T_world_cam.translation();
  const Eigen::Matrix3f R = T_world_cam.linear();
  const int tw = (cam.width + kTile - 1) / kTile, th = (cam.height + kTile - 1) / kTile;
  std::vector<float> tile_near, tile_far;
  tileBounds(map, cam, T_world_cam.inverse(), static_cast<float>(params.max_depth_m), tile_near, tile_far, tw, th);
  std::atomic<int> valid{0};
  parallel(static_cast<size_t>(cam.height), [&](size_t v0, size_t v1) {
    int local_valid = 0;
    BlockCache cache(map);
    for (int v = static_cast<int>(v0); v < static_cast<int>(v1); ++v) {
      float* drow = view.depth.ptr<float>(v);
      auto* vrow = view.vertex_world.ptr<cv::Vec3f>(v);
      for (int u = 0; u < cam.width; ++u) {
        const size_t tile = static_cast<size_t>((v / kTile) * tw + u / kTile);
        if (tile_near[tile] > tile_far[tile]) continue;
        const Eigen::Vector3f ray_cam = cam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
        Ray ray;
        ray.origin = origin;
        ray.len = ray_cam.norm();
        ray.dir = R * ray_cam / ray.len;
        ray.inv_dir = ray.dir.cwiseInverse();
        const float tile_start = std::max(static_cast<float>(params.min_depth_m), tile_near[tile] - vs) * ray.len;
        const float t_max = std::min(static_cast<float>(params.max_depth_m), tile_far[tile] + vs) * ray.len;
        const float predicted = hinted ? depth_hint.ptr<float>(v)[u] : 0.0f;
        // A pixel without a prediction first tries its left neighbour's hit
        // of this cast as one: holes in the prediction that the map can
        // fill grow in from their edges at three samples per pixel instead
        // of a march each. When that fails the pixel is treated as its own
        // prediction says (march from the tile bound, or not cast).
        float zh = predicted;
        const bool from_neighbour = predicted <= 0.0f && u > 0 && drow[u - 1] > 0.0f;
        if (from_neighbour) zh = drow[u - 1];
        if (zh < 0.0f) continue;  // predicted empty
        float hit = -1;
        if (zh > 0.0f) {
          bool sampled = false;
          hit = hitNearDepth(cache, ray, mp, zh, tile_start, sampled);
          if (!sampled && !from_neighbour) continue;
          if (hit < 0 && from_neighbour) {
            if (predicted < 0.0f) continue;
            zh = 0.0f;  // march from the tile bound
          }
        }
        if (hit < 0) {
          // A predicted surface, if any, lies within the truncation band
          // around the prediction: the march covers that band only.
          float t = tile_start, t_end = t_max;
          bool from_hint = false;
          if (zh > 0.0f) {
            const float start = (zh - mp.mu - 2.0f * vs) * ray.len;
            t_end = std::min(t_max, (zh + mp.mu + 2.0f * vs) * ray.len);
            if (start > t) {
              t = start;
              from_hint = true;
            }
          }
          hit = march(map, cache, ray, mp, t, t_end, from_hint, tile_start);
        }
        if (hit < 0) continue;
        const Eigen::Vector3f p = origin + hit * ray.dir;
        drow[u] = hit / ray.len;
        vrow[u] = cv::Vec3f(p.x(), p.y(), p.z());
        ++local_valid;
        Eigen::Vector3f c;
        if (with_color && cache.sampleColor(p, c)) {  // in [0, 255]: +0.5 and truncation round
          view.rgb.at<cv::Vec3b>(v, u) =
              cv::Vec3b(static_cast<uint8_t>(c.x() + 0.5f), static_cast<uint8_t>(c.y() + 0.5f),
                        static_cast<uint8_t>(c.z() + 0.5f));
        }
      }
    }
    valid += local_valid;
  });
  view.valid_pixels = valid;
  normalsFromVertices(view, origin, vs);
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
