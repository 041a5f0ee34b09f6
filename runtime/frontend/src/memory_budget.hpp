// What a map under a memory budget moves out and brings back, given a
// camera: shared by the frontend's map and loop closure's keyframe map.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/geometry/camera.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt::budget {

/// Whether a block (center c in the camera frame) can be in the view of a
/// camera out to max_depth_m; `radius` is half the block's diagonal.
inline bool blockInView(const Eigen::Vector3f& c, float radius, const alg::PinholeCamera& cam, float max_depth_m) {
  if (c.z() < -radius || c.z() > max_depth_m + radius) return false;
  const float z = std::max(c.z(), 0.05f);
  const float mu = static_cast<float>(cam.fx) * radius / z, mv = static_cast<float>(cam.fy) * radius / z;
  const float u = static_cast<float>(cam.fx) * c.x() / z + static_cast<float>(cam.cx);
  const float v = static_cast<float>(cam.fy) * c.y() / z + static_cast<float>(cam.cy);
  return u > -mu && u < static_cast<float>(cam.width) + mu && v > -mv && v < static_cast<float>(cam.height) + mv;
}

/// The center of block `key` in the frame T_cam_world maps the world to.
inline Eigen::Vector3f blockCenter(const Eigen::Isometry3f& T_cam_world, const alg::BlockKey& key, float block_size) {
  return T_cam_world * (key.cast<float>() * block_size + Eigen::Vector3f::Constant(0.5f * block_size));
}

/// The blocks out of memory a camera at T_cam_world can see, with their
/// depth: (depth, packed key). Cubes of blocks out of view are skipped
/// whole: the cost follows the view, not the length of the path.
inline std::vector<std::pair<float, uint64_t>> blocksOutInView(const alg::TsdfMap& map,
                                                               const Eigen::Isometry3f& T_cam_world,
                                                               const alg::PinholeCamera& cam, float max_depth_m) {
  const float radius = 0.5f * map.blockSize() * std::sqrt(3.0f);
  const float side = alg::BlockKeySet::kRegionSide * map.blockSize();
  const float region_radius = 0.5f * side * std::sqrt(3.0f);
  std::vector<std::pair<float, uint64_t>> out;
  map.blocksElsewhere().forEachIn(
      [&](const alg::BlockKey& lo) {
        const Eigen::Vector3f c =
            T_cam_world * (lo.cast<float>() * map.blockSize() + Eigen::Vector3f::Constant(0.5f * side));
        return blockInView(c, region_radius, cam, max_depth_m);
      },
      [&](const alg::BlockKey& k) {
        const Eigen::Vector3f c = blockCenter(T_cam_world, k, map.blockSize());
        if (blockInView(c, radius, cam, max_depth_m)) out.emplace_back(c.z(), alg::packBlockKey(k));
      });
  return out;
}

/// How many blocks to move out of a map of `resident` bytes under
/// `budget`: none below 90 %, down to 80 %, at most `cap` a call unless more
/// must go to end within the budget (and a chunk more: memory is freed a
/// chunk at a time).
inline size_t blocksToMoveOut(size_t resident, size_t budget, size_t cap, size_t blocks) {
  if (resident <= budget * 9 / 10) return 0;
  const size_t block_bytes = sizeof(alg::VoxelBlock);
  const size_t to_80 = (resident - budget * 8 / 10 + block_bytes - 1) / block_bytes;
  const size_t to_100 =
      resident > budget ? (resident - budget + block_bytes - 1) / block_bytes + alg::TsdfMap::chunkBlocks() : 0;
  return std::min({to_80, std::max(to_100, std::max<size_t>(cap, 1)), blocks});
}

/// The `count` resident blocks farthest from a camera at T_cam_world
/// (those in its view counted four times nearer), by index.
inline std::vector<int32_t> farthestBlocks(const alg::TsdfMap& map, const Eigen::Isometry3f& T_cam_world,
                                           const alg::PinholeCamera& cam, float max_depth_m, size_t count) {
  count = std::min(count, map.blockCount());
  if (count == 0) return {};
  const float radius = 0.5f * map.blockSize() * std::sqrt(3.0f);
  std::vector<std::pair<float, int32_t>> far;  // -score, index
  far.reserve(map.blockCount());
  for (size_t i = 0; i < map.blockCount(); ++i) {
    const Eigen::Vector3f c = blockCenter(T_cam_world, map.key(i), map.blockSize());
    const float d = c.norm() * (blockInView(c, radius, cam, max_depth_m) ? 0.25f : 1.0f);
    far.emplace_back(-d, static_cast<int32_t>(i));
  }
  std::nth_element(far.begin(), far.begin() + static_cast<std::ptrdiff_t>(count - 1), far.end());
  std::vector<int32_t> victims;
  victims.reserve(count);
  for (size_t i = 0; i < count; ++i) victims.push_back(far[i].second);
  return victims;
}

}  // namespace hxmap::rt::budget
