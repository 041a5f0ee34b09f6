#include "hxmap/tsdf/patch.hpp"

#include <algorithm>
#include <cmath>

namespace hxmap::alg {

PatchStats applyPatch(TsdfMap& map, const TsdfPatch& patch) {
  PatchStats stats;
  const float mu = map.truncation();
  const float max_w = static_cast<float>(map.params().max_weight);
  const size_t before = map.blockCount();
  std::vector<int32_t> written;
  for (const auto& e : patch.entries) {
    if (!std::isfinite(e.sdf_m) || !std::isfinite(e.weight) || !(e.weight > 0.0f)) {
      ++stats.rejected;
      continue;
    }
    const BlockKey key(e.voxel.x() >> 3, e.voxel.y() >> 3, e.voxel.z() >> 3);
    const int32_t b = map.findOrAllocate(key);
    if (written.empty() || written.back() != b) written.push_back(b);
    VoxelBlock& blk = map.block(static_cast<size_t>(b));
    VoxelGeometry& g = blk.geo[VoxelBlock::index(e.voxel.x() & 7, e.voxel.y() & 7, e.voxel.z() & 7)];
    const float s = std::clamp(e.sdf_m, -mu, mu);
    const float new_w = g.weight + e.weight;
    const float a = e.weight / new_w;
    g.sdf_m += a * (s - g.sdf_m);
    if (e.has_color) {
      const int i = VoxelBlock::index(e.voxel.x() & 7, e.voxel.y() & 7, e.voxel.z() & 7);
      // A voxel with no in-band observation has no color yet (see
      // fuseAppearance): the patch's sets it.
      const float ac = blk.stats[i].updates == 0 ? 1.0f : a;
      VoxelColor& c = blk.color[i];
      c.r = static_cast<uint8_t>(c.r + ac * (static_cast<float>(e.rgb[0]) - c.r) + 0.5f);
      c.g = static_cast<uint8_t>(c.g + ac * (static_cast<float>(e.rgb[1]) - c.g) + 0.5f);
      c.b = static_cast<uint8_t>(c.b + ac * (static_cast<float>(e.rgb[2]) - c.b) + 0.5f);
    }
    g.weight = std::min(new_w, max_w);
    uint8_t& flags = blk.color[VoxelBlock::index(e.voxel.x() & 7, e.voxel.y() & 7, e.voxel.z() & 7)].flags;
    if (g.sdf_m <= 0.0f) {
      flags &= static_cast<uint8_t>(~kVoxelSeenThrough);
    } else if (e.seen_through) {
      flags |= kVoxelSeenThrough;
      blk.seen_through = true;
      ++stats.seen_through;
    }
    ++stats.applied;
  }
  stats.blocks_allocated = map.blockCount() - before;
  std::sort(written.begin(), written.end());
  written.erase(std::unique(written.begin(), written.end()), written.end());
  map.markChanged(written);
  return stats;
}

}  // namespace hxmap::alg
