#include "hxmap/tsdf/integrate.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>

namespace hxmap::alg {

std::vector<int32_t> allocateBand(TsdfMap& map, const DepthObservation& obs, size_t* newly_allocated) {
  const float mu = map.truncation();
  const float max_depth = static_cast<float>(map.params().max_integration_depth_m);
  const float min_conf = static_cast<float>(map.params().min_confidence);
  const int stride = std::max(1, map.params().allocation_stride_px);
  const float step = map.blockSize() * 0.5f;
  const size_t before = map.blockCount();
  std::vector<int32_t> touched;
  std::vector<uint8_t> mark(map.blockCount(), 0);
  auto touch = [&](const Eigen::Vector3f& p) {
    const int32_t b = map.findOrAllocate(map.blockOf(p));
    if (static_cast<size_t>(b) >= mark.size()) mark.resize(b + 1, 0);
    if (!mark[b]) {
      mark[b] = 1;
      touched.push_back(b);
    }
  };
  const bool has_conf = !obs.confidence.empty();
  for (int v = stride / 2; v < obs.depth_m.rows; v += stride) {
    const float* drow = obs.depth_m.ptr<float>(v);
    const float* crow = has_conf ? obs.confidence.ptr<float>(v) : nullptr;
    for (int u = stride / 2; u < obs.depth_m.cols; u += stride) {
      const float z = drow[u];
      if (!(z > 0) || z > max_depth || (crow && crow[u] < min_conf)) continue;
      const Eigen::Vector3f ray = obs.camera.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
      const float len = ray.norm();
      // Along-ray band [z - mu, z + mu] in depth units.
      const float z0 = std::max(0.01f, z - mu), z1 = z + mu;
      const Eigen::Vector3f a = obs.T_world_cam * (ray * z0), b = obs.T_world_cam * (ray * z1);
      const float length = (z1 - z0) * len;
      const int n = std::max(1, static_cast<int>(std::ceil(length / step)));
      for (int k = 0; k <= n; ++k) touch(a + (b - a) * (static_cast<float>(k) / static_cast<float>(n)));
    }
  }
  if (newly_allocated) *newly_allocated = map.blockCount() - before;
  return touched;
}

namespace {

inline void fuse(Voxel& vx, float tsdf, float w, float max_w, const uint8_t* rgb, float mu) {
  const float new_w = vx.weight + w;
  vx.sdf_m = (vx.sdf_m * vx.weight + tsdf * w) / new_w;
  if (rgb && tsdf < mu) {
    const float a = w / new_w;
    vx.r = static_cast<uint8_t>(std::lround(vx.r + a * (static_cast<float>(rgb[0]) - vx.r)));
    vx.g = static_cast<uint8_t>(std::lround(vx.g + a * (static_cast<float>(rgb[1]) - vx.g)));
    vx.b = static_cast<uint8_t>(std::lround(vx.b + a * (static_cast<float>(rgb[2]) - vx.b)));
  }
  vx.weight = std::min(new_w, max_w);
  if (tsdf < mu) {  // statistics of surface observations, not free-space clamps
    ++vx.updates;
    const float delta = tsdf - vx.update_mean_m;
    vx.update_mean_m += delta / static_cast<float>(vx.updates);
    vx.update_m2 += delta * (tsdf - vx.update_mean_m);
  }
}

}  // namespace

IntegrationStats integrate(TsdfMap& map, const DepthObservation& obs, const ParallelFor& parallel) {
  IntegrationStats stats;
  const std::vector<int32_t> blocks = allocateBand(map, obs, &stats.blocks_allocated);
  stats.blocks_in_band = blocks.size();
  const Eigen::Isometry3f T_cam_world = obs.T_world_cam.inverse();
  const Eigen::Matrix3f R = T_cam_world.linear();
  const float vs = map.voxelSize(), mu = map.truncation();
  const float max_w = static_cast<float>(map.params().max_weight);
  const float max_depth = static_cast<float>(map.params().max_integration_depth_m);
  const float min_conf = static_cast<float>(map.params().min_confidence);
  const float fx = static_cast<float>(obs.camera.fx), fy = static_cast<float>(obs.camera.fy);
  const float cx = static_cast<float>(obs.camera.cx), cy = static_cast<float>(obs.camera.cy);
  const int W = obs.depth_m.cols, H = obs.depth_m.rows;
  const bool has_rgb = !obs.rgb.empty(), has_conf = !obs.confidence.empty();
  const Eigen::Vector3f dx = R.col(0) * vs, dy = R.col(1) * vs, dz = R.col(2) * vs;
  std::atomic<size_t> updated{0};
  parallel(blocks.size(), [&](size_t begin, size_t end) {
    size_t local_updates = 0;
    for (size_t bi = begin; bi < end; ++bi) {
      const int32_t b = blocks[bi];
      VoxelBlock& block = map.block(b);
      const Eigen::Vector3f origin_world = (map.key(b) * kBlockSide).cast<float>() * vs + Eigen::Vector3f::Constant(0.5f * vs);
      const Eigen::Vector3f origin_cam = T_cam_world * origin_world;
      for (int z = 0; z < kBlockSide; ++z) {
        for (int y = 0; y < kBlockSide; ++y) {
          Eigen::Vector3f p = origin_cam + dz * static_cast<float>(z) + dy * static_cast<float>(y);
          Voxel* row = &block.voxels[VoxelBlock::index(0, y, z)];
          for (int x = 0; x < kBlockSide; ++x, p += dx) {
            if (p.z() <= 0.0f) continue;
            const float inv_z = 1.0f / p.z();
            const int u = static_cast<int>(std::lround(fx * p.x() * inv_z + cx));
            const int v = static_cast<int>(std::lround(fy * p.y() * inv_z + cy));
            if (u < 0 || v < 0 || u >= W || v >= H) continue;
            const float d = obs.depth_m.ptr<float>(v)[u];
            if (!(d > 0.0f) || d > max_depth) continue;
            const float sdf = d - p.z();
            if (sdf < -mu) continue;
            const float c = has_conf ? obs.confidence.ptr<float>(v)[u] : 1.0f;
            if (c < min_conf || c <= 0.0f) continue;
            const uint8_t* rgb = has_rgb ? obs.rgb.ptr<uint8_t>(v) + 3 * u : nullptr;
            fuse(row[x], std::min(sdf, mu), c, max_w, rgb, mu);
            ++local_updates;
          }
        }
      }
    }
    updated += local_updates;
  });
  stats.voxels_updated = updated;
  return stats;
}

IntegrationStats integrateReference(TsdfMap& map, const DepthObservation& obs) {
  IntegrationStats stats;
  const std::vector<int32_t> blocks = allocateBand(map, obs, &stats.blocks_allocated);
  stats.blocks_in_band = blocks.size();
  const Eigen::Isometry3d T_cam_world = obs.T_world_cam.cast<double>().inverse();
  const double mu = map.params().truncation_m;
  for (const int32_t b : blocks) {
    for (int i = 0; i < kBlockVoxels; ++i) {
      const int x = i % kBlockSide, y = (i / kBlockSide) % kBlockSide, z = i / (kBlockSide * kBlockSide);
      const Eigen::Vector3i global = map.key(b) * kBlockSide + Eigen::Vector3i(x, y, z);
      const Eigen::Vector3d p = T_cam_world * map.voxelCenter(global).cast<double>();
      if (p.z() <= 0) continue;
      const double u = obs.camera.fx * p.x() / p.z() + obs.camera.cx;
      const double v = obs.camera.fy * p.y() / p.z() + obs.camera.cy;
      const int ui = static_cast<int>(std::lround(u)), vi = static_cast<int>(std::lround(v));
      if (ui < 0 || vi < 0 || ui >= obs.depth_m.cols || vi >= obs.depth_m.rows) continue;
      const double d = obs.depth_m.at<float>(vi, ui);
      if (!(d > 0) || d > map.params().max_integration_depth_m) continue;
      const double sdf = d - p.z();
      if (sdf < -mu) continue;
      const double c = obs.confidence.empty() ? 1.0 : obs.confidence.at<float>(vi, ui);
      if (c < map.params().min_confidence || c <= 0) continue;
      const uint8_t* rgb = obs.rgb.empty() ? nullptr : obs.rgb.ptr<uint8_t>(vi) + 3 * ui;
      fuse(map.block(b).voxels[i], static_cast<float>(std::min(sdf, mu)), static_cast<float>(c),
           static_cast<float>(map.params().max_weight), rgb, static_cast<float>(mu));
      ++stats.voxels_updated;
    }
  }
  return stats;
}

}  // namespace hxmap::alg
