// A block's voxels as the bytes map files and the block store compress:
// 512 (sdf, weight), then 512 colors, then 512 statistics, little-endian.
#pragma once

#include <cstring>
#include <string>

#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::drv {

static_assert(sizeof(alg::VoxelGeometry) == 8 && sizeof(alg::VoxelColor) == 4 && sizeof(alg::VoxelStats) == 12,
              "the voxel record layout of map files and the block store");
constexpr size_t kVoxelRecordBytes = sizeof(alg::VoxelGeometry) + sizeof(alg::VoxelColor) + sizeof(alg::VoxelStats);
constexpr size_t kBlockRawBytes = alg::kBlockVoxels * kVoxelRecordBytes;

/// The block's voxels into `raw` (resized to kBlockRawBytes).
inline void packBlock(const alg::VoxelBlock& b, std::string& raw) {
  raw.resize(kBlockRawBytes);
  char* p = raw.data();
  std::memcpy(p, b.geo, sizeof b.geo);
  std::memcpy(p + sizeof b.geo, b.color, sizeof b.color);
  std::memcpy(p + sizeof b.geo + sizeof b.color, b.stats, sizeof b.stats);
}

/// kBlockRawBytes of `raw` into the block's voxels (seen_through aside).
inline void unpackBlock(const char* raw, alg::VoxelBlock& b) {
  std::memcpy(b.geo, raw, sizeof b.geo);
  std::memcpy(b.color, raw + sizeof b.geo, sizeof b.color);
  std::memcpy(b.stats, raw + sizeof b.geo + sizeof b.color, sizeof b.stats);
}

}  // namespace hxmap::drv
