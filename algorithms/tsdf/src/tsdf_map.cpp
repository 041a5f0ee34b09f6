#include "hxmap/tsdf/tsdf_map.hpp"

#include <cmath>

namespace hxmap::alg {

TsdfMap::TsdfMap(const TsdfParams& params)
    : params_(params),
      voxel_size_(static_cast<float>(params.voxel_size_m)),
      truncation_(static_cast<float>(params.truncation_m)),
      inv_voxel_size_(1.0f / voxel_size_),
      inv_block_size_(1.0f / (voxel_size_ * kBlockSide)) {
  rehash(1 << 12);
}


void TsdfMap::rehash(size_t capacity) {
  table_keys_.assign(capacity, 0);
  table_values_.assign(capacity, -1);
  const size_t mask = capacity - 1;
  for (size_t i = 0; i < keys_.size(); ++i) {
    const uint64_t packed = pack(keys_[i]) + 1;
    size_t s = slotOf(packed, mask);
    while (table_keys_[s] != 0) s = (s + 1) & mask;
    table_keys_[s] = packed;
    table_values_[s] = static_cast<int32_t>(i);
  }
}

int32_t TsdfMap::findOrAllocate(const BlockKey& key) {
  const int32_t found = find(key);
  if (found >= 0) return found;
  if ((keys_.size() + 1) * 2 > table_keys_.size()) rehash(table_keys_.size() * 2);
  const int32_t index = static_cast<int32_t>(keys_.size());
  keys_.push_back(key);
  blocks_.emplace_back();
  const uint64_t packed = pack(key) + 1;
  const size_t mask = table_keys_.size() - 1;
  size_t s = slotOf(packed, mask);
  while (table_keys_[s] != 0) s = (s + 1) & mask;
  table_keys_[s] = packed;
  table_values_[s] = index;
  return index;
}

const Voxel* TsdfMap::voxel(const Eigen::Vector3i& g) const {
  const BlockKey key(floorDiv(g.x(), kBlockSide), floorDiv(g.y(), kBlockSide), floorDiv(g.z(), kBlockSide));
  const int32_t b = find(key);
  if (b < 0) return nullptr;
  const Eigen::Vector3i l = g - key * kBlockSide;
  return &blocks_[b].voxels[VoxelBlock::index(l.x(), l.y(), l.z())];
}

namespace {
// The 8 voxels around p and the trilinear weights; false when one is missing.
template <typename Map>
bool gatherCorners(const Map& map, const Eigen::Vector3f& p, float min_weight, const Voxel* corners[8],
                   Eigen::Vector3f& frac) {
  const Eigen::Vector3f q = p / map.voxelSize() - Eigen::Vector3f::Constant(0.5f);
  const Eigen::Vector3f f = q.array().floor();
  const Eigen::Vector3i base = f.cast<int>();
  frac = q - f;
  const BlockKey key(floorDiv(base.x(), kBlockSide), floorDiv(base.y(), kBlockSide), floorDiv(base.z(), kBlockSide));
  const Eigen::Vector3i local = base - key * kBlockSide;
  if (local.maxCoeff() < kBlockSide - 1) {  // all 8 inside one block: one lookup
    const int32_t b = map.find(key);
    if (b < 0) return false;
    const VoxelBlock& block = map.block(b);
    for (int c = 0; c < 8; ++c) {
      corners[c] = &block.voxels[VoxelBlock::index(local.x() + (c & 1), local.y() + ((c >> 1) & 1),
                                                    local.z() + ((c >> 2) & 1))];
      if (corners[c]->weight < min_weight || corners[c]->weight <= 0) return false;
    }
    return true;
  }
  for (int c = 0; c < 8; ++c) {
    corners[c] = map.voxel(base + Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1));
    if (corners[c] == nullptr || corners[c]->weight < min_weight || corners[c]->weight <= 0) return false;
  }
  return true;
}

inline float cornerWeight(int c, const Eigen::Vector3f& f) {
  return ((c & 1) ? f.x() : 1 - f.x()) * (((c >> 1) & 1) ? f.y() : 1 - f.y()) * (((c >> 2) & 1) ? f.z() : 1 - f.z());
}
}  // namespace

bool TsdfMap::sample(const Eigen::Vector3f& p, float min_weight, float& sdf) const {
  const Voxel* corners[8];
  Eigen::Vector3f f;
  if (!gatherCorners(*this, p, min_weight, corners, f)) return false;
  float s = 0;
  for (int c = 0; c < 8; ++c) s += cornerWeight(c, f) * corners[c]->sdf_m;
  sdf = s;
  return true;
}

bool TsdfMap::sampleColor(const Eigen::Vector3f& p, Eigen::Vector3f& rgb) const {
  const Voxel* corners[8];
  Eigen::Vector3f f;
  if (!gatherCorners(*this, p, 0.0f, corners, f)) return false;
  rgb.setZero();
  for (int c = 0; c < 8; ++c) rgb += cornerWeight(c, f) * Eigen::Vector3f(corners[c]->r, corners[c]->g, corners[c]->b);
  return true;
}

MapMemory TsdfMap::memory() const {
  return {keys_.size(), keys_.size() * (sizeof(VoxelBlock) + sizeof(BlockKey)) +
                            table_keys_.size() * (sizeof(uint64_t) + sizeof(int32_t))};
}

void TsdfMap::clear() {
  blocks_.clear();
  keys_.clear();
  rehash(1 << 12);
}

}  // namespace hxmap::alg
