#include "hxmap/tsdf/tsdf_map.hpp"

#include <algorithm>
#include <cmath>
#include <functional>

namespace hxmap::alg {

TsdfMap::TsdfMap(const TsdfParams& params)
    : params_(params),
      voxel_size_(static_cast<float>(params.voxel_size_m)),
      truncation_(static_cast<float>(params.truncation_m)),
      inv_voxel_size_(1.0f / voxel_size_),
      inv_block_size_(1.0f / (voxel_size_ * kBlockSide)) {
  rehash(1 << 12);
}

TsdfMap::TsdfMap(const TsdfMap& other)
    : params_(other.params_),
      voxel_size_(other.voxel_size_),
      truncation_(other.truncation_),
      inv_voxel_size_(other.inv_voxel_size_),
      inv_block_size_(other.inv_block_size_),
      stale_end_(other.stale_end_),
      keys_(other.keys_),
      block_revisions_(other.block_revisions_),
      revision_(other.revision_),
      table_keys_(other.table_keys_),
      table_values_(other.table_values_),
      elsewhere_(other.elsewhere_) {
  chunks_.reserve(other.chunks_.size());
  for (const auto& chunk : other.chunks_) {
    addChunk();
    std::copy(chunk.get(), chunk.get() + kChunkBlocks, chunks_.back().get());
  }
}

void TsdfMap::addChunk() {
  chunks_.push_back(std::make_shared<VoxelBlock[]>(kChunkBlocks));
  chunk_generation_.push_back(generation_);
}

void TsdfMap::ownChunk(size_t chunk) {
  if (snapshots_alive_ && snapshots_alive_->load(std::memory_order_acquire) == 0) {
    shared_below_ = 0;  // no snapshot reads the chunks any more
    return;
  }
  auto own = std::make_shared<VoxelBlock[]>(kChunkBlocks);
  std::copy(chunks_[chunk].get(), chunks_[chunk].get() + kChunkBlocks, own.get());
  chunks_[chunk] = std::move(own);
  chunk_generation_[chunk] = generation_;
  ++chunks_copied_on_write_;
}

void TsdfMap::prepareWrites(const std::vector<int32_t>& block_indices) {
  for (const int32_t b : block_indices) {
    const size_t c = static_cast<size_t>(b) / kChunkBlocks;
    if (chunk_generation_[c] < shared_below_) ownChunk(c);
  }
}

TsdfMap TsdfMap::snapshot() {
  TsdfMap out(params_);
  out.stale_end_ = stale_end_;
  out.keys_ = keys_;
  out.block_revisions_ = block_revisions_;
  out.revision_ = revision_;
  out.table_keys_ = table_keys_;
  out.table_values_ = table_values_;
  out.elsewhere_ = elsewhere_;
  out.chunks_ = chunks_;
  // Every chunk now is below both maps' line; chunks added or copied
  // later are above it.
  ++generation_;
  shared_below_ = generation_;
  out.chunk_generation_ = chunk_generation_;
  out.generation_ = out.shared_below_ = generation_;
  if (!snapshots_alive_) snapshots_alive_ = std::make_shared<std::atomic<int>>(0);
  snapshots_alive_->fetch_add(1, std::memory_order_relaxed);
  out.hold_.count = snapshots_alive_;
  return out;
}

TsdfMap& TsdfMap::operator=(const TsdfMap& other) {
  if (this != &other) *this = TsdfMap(other);
  return *this;
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
  if (keys_.size() > chunks_.size() * kChunkBlocks) addChunk();
  if (static_cast<size_t>(index) < stale_end_) block(static_cast<size_t>(index)) = VoxelBlock{};
  block_revisions_.push_back(0);
  if (!elsewhere_.empty()) {
    if (elsewhere_.erase(key)) {
      if (backing_ && backing_->take(key, block(static_cast<size_t>(index)))) {
        ++taken_back_;
      } else {
        block(static_cast<size_t>(index)) = VoxelBlock{};  // a partial read leaves nothing behind
        ++lost_in_backing_;
      }
    }
  }
  const uint64_t packed = pack(key) + 1;
  const size_t mask = table_keys_.size() - 1;
  size_t s = slotOf(packed, mask);
  while (table_keys_[s] != 0) s = (s + 1) & mask;
  table_keys_[s] = packed;
  table_values_[s] = index;
  return index;
}

bool TsdfMap::voxel(const Eigen::Vector3i& g, Voxel& out) const {
  int i = 0;
  const VoxelBlock* blk = blockOfVoxel(g, i);
  if (blk == nullptr) return false;
  out.sdf_m = blk->geo[i].sdf_m;
  out.weight = blk->geo[i].weight;
  out.color = blk->color[i];
  out.stats = blk->stats[i];
  return true;
}

namespace {
// The 8 voxels around p (block and index of each) and the trilinear
// fractions; false when one is missing or has too little weight.
bool gatherCorners(BlockCache& cache, float inv_voxel, const Eigen::Vector3f& p, float min_weight,
                   const VoxelBlock* blocks[8], int index[8], Eigen::Vector3f& frac) {
  const float qx = p.x() * inv_voxel - 0.5f, qy = p.y() * inv_voxel - 0.5f, qz = p.z() * inv_voxel - 0.5f;
  const int bx = floorToInt(qx), by = floorToInt(qy), bz = floorToInt(qz);  // no libm floor
  frac = Eigen::Vector3f(qx - static_cast<float>(bx), qy - static_cast<float>(by), qz - static_cast<float>(bz));
  for (int c = 0; c < 8; ++c) {  // the cache makes repeated blocks cheap
    blocks[c] = cache.blockOfVoxel(Eigen::Vector3i(bx + (c & 1), by + ((c >> 1) & 1), bz + ((c >> 2) & 1)), index[c]);
    if (blocks[c] == nullptr) return false;
    const float w = blocks[c]->geo[index[c]].weight;
    if (w < min_weight || w <= 0) return false;
  }
  return true;
}

inline float cornerWeight(int c, const Eigen::Vector3f& f) {
  return ((c & 1) ? f.x() : 1 - f.x()) * (((c >> 1) & 1) ? f.y() : 1 - f.y()) * (((c >> 2) & 1) ? f.z() : 1 - f.z());
}
}  // namespace

bool BlockCache::sample(const Eigen::Vector3f& p, float min_weight, float& sdf) {
  // Fast path (343 of 512 positions): all 8 corners in one block, read as
  // four x-adjacent pairs and blended by successive lerps.
  const float qx = p.x() * map_->invVoxelSize() - 0.5f, qy = p.y() * map_->invVoxelSize() - 0.5f,
              qz = p.z() * map_->invVoxelSize() - 0.5f;
  const int bx = floorToInt(qx), by = floorToInt(qy), bz = floorToInt(qz);
  if ((bx & 7) < 7 && (by & 7) < 7 && (bz & 7) < 7) {
    const VoxelBlock* blk = get(BlockKey(bx >> 3, by >> 3, bz >> 3));
    if (blk == nullptr) return false;
    const int i0 = VoxelBlock::index(bx & 7, by & 7, bz & 7);
    constexpr int dy = kBlockSide, dz = kBlockSide * kBlockSide;
    const VoxelGeometry* g = blk->geo + i0;
    const float w_min =
        std::min(std::min(std::min(g[0].weight, g[1].weight), std::min(g[dy].weight, g[dy + 1].weight)),
                 std::min(std::min(g[dz].weight, g[dz + 1].weight), std::min(g[dz + dy].weight, g[dz + dy + 1].weight)));
    if (!(w_min > 0.0f) || w_min < min_weight) return false;
    const float s[] = {g[0].sdf_m, g[1].sdf_m, g[dy].sdf_m, g[dy + 1].sdf_m};
    const float t[] = {g[dz].sdf_m, g[dz + 1].sdf_m, g[dz + dy].sdf_m, g[dz + dy + 1].sdf_m};
    const float fx = qx - static_cast<float>(bx), fy = qy - static_cast<float>(by), fz = qz - static_cast<float>(bz);
    const float s00 = s[0] + fx * (s[1] - s[0]), s10 = s[2] + fx * (s[3] - s[2]);
    const float s01 = t[0] + fx * (t[1] - t[0]), s11 = t[2] + fx * (t[3] - t[2]);
    const float s0 = s00 + fy * (s10 - s00), s1 = s01 + fy * (s11 - s01);
    sdf = s0 + fz * (s1 - s0);
    return true;
  }
  const VoxelBlock* blocks[8];
  int index[8];
  Eigen::Vector3f f;
  if (!gatherCorners(*this, map_->invVoxelSize(), p, min_weight, blocks, index, f)) return false;
  float s = 0;
  for (int c = 0; c < 8; ++c) s += cornerWeight(c, f) * blocks[c]->geo[index[c]].sdf_m;
  sdf = s;
  return true;
}

bool BlockCache::sampleColor(const Eigen::Vector3f& p, Eigen::Vector3f& rgb) {
  const VoxelBlock* blocks[8];
  int index[8];
  Eigen::Vector3f f;
  if (!gatherCorners(*this, map_->invVoxelSize(), p, 0.0f, blocks, index, f)) return false;
  rgb.setZero();
  for (int c = 0; c < 8; ++c) {
    const VoxelColor& k = blocks[c]->color[index[c]];
    rgb += cornerWeight(c, f) * Eigen::Vector3f(k.r, k.g, k.b);
  }
  return true;
}

bool BlockCache::sampleWithGradient(const Eigen::Vector3f& p, float min_weight, float& sdf, Eigen::Vector3f& gradient,
                                    Eigen::Vector3f& rgb) {
  return sampleWithGradient(p, min_weight, sdf, gradient, &rgb);
}

bool BlockCache::sampleWithGradient(const Eigen::Vector3f& p, float min_weight, float& sdf, Eigen::Vector3f& gradient,
                                    Eigen::Vector3f* rgb) {
  const VoxelBlock* blocks[8];
  int index[8];
  Eigen::Vector3f f;
  // Fast path as in sample(): the 8 corners in one block, no per-corner lookup.
  const Eigen::Vector3f q = p * map_->invVoxelSize() - Eigen::Vector3f::Constant(0.5f);
  const int bx = floorToInt(q.x()), by = floorToInt(q.y()), bz = floorToInt(q.z());
  if ((bx & 7) < 7 && (by & 7) < 7 && (bz & 7) < 7) {
    const VoxelBlock* blk = get(BlockKey(bx >> 3, by >> 3, bz >> 3));
    if (blk == nullptr) return false;
    const int i0 = VoxelBlock::index(bx & 7, by & 7, bz & 7);
    for (int c = 0; c < 8; ++c) {
      blocks[c] = blk;
      index[c] = i0 + (c & 1) + ((c >> 1) & 1) * kBlockSide + ((c >> 2) & 1) * kBlockSide * kBlockSide;
      const float w = blk->geo[index[c]].weight;
      if (w < min_weight || w <= 0) return false;
    }
    f = q - Eigen::Vector3f(static_cast<float>(bx), static_cast<float>(by), static_cast<float>(bz));
  } else if (!gatherCorners(*this, map_->invVoxelSize(), p, min_weight, blocks, index, f)) {
    return false;
  }
  float s[8];
  sdf = 0;
  for (int c = 0; c < 8; ++c) {
    s[c] = blocks[c]->geo[index[c]].sdf_m;
    sdf += cornerWeight(c, f) * s[c];
  }
  if (rgb) {
    rgb->setZero();
    for (int c = 0; c < 8; ++c) {
      const VoxelColor& k = blocks[c]->color[index[c]];
      *rgb += cornerWeight(c, f) * Eigen::Vector3f(k.r, k.g, k.b);
    }
  }
  // Corner c = x | y << 1 | z << 2: differences along each axis, blended
  // over the other two.
  const float fx = f.x(), fy = f.y(), fz = f.z();
  const float dx = (1 - fy) * (1 - fz) * (s[1] - s[0]) + fy * (1 - fz) * (s[3] - s[2]) + (1 - fy) * fz * (s[5] - s[4]) +
                   fy * fz * (s[7] - s[6]);
  const float dy = (1 - fx) * (1 - fz) * (s[2] - s[0]) + fx * (1 - fz) * (s[3] - s[1]) + (1 - fx) * fz * (s[6] - s[4]) +
                   fx * fz * (s[7] - s[5]);
  const float dz = (1 - fx) * (1 - fy) * (s[4] - s[0]) + fx * (1 - fy) * (s[5] - s[1]) + (1 - fx) * fy * (s[6] - s[2]) +
                   fx * fy * (s[7] - s[3]);
  gradient = Eigen::Vector3f(dx, dy, dz) * map_->invVoxelSize();
  return true;
}

bool TsdfMap::sample(const Eigen::Vector3f& p, float min_weight, float& sdf) const {
  BlockCache cache(*this);
  return cache.sample(p, min_weight, sdf);
}

bool TsdfMap::sampleColor(const Eigen::Vector3f& p, Eigen::Vector3f& rgb) const {
  BlockCache cache(*this);
  return cache.sampleColor(p, rgb);
}

MapMemory TsdfMap::memory() const {
  return {keys_.size(), chunks_.size() * kChunkBlocks * sizeof(VoxelBlock) + keys_.size() * sizeof(BlockKey) +
                            table_keys_.size() * (sizeof(uint64_t) + sizeof(int32_t))};
}

void TsdfMap::markChanged(const std::vector<int32_t>& block_indices) {
  ++revision_;
  for (const int32_t b : block_indices) block_revisions_[static_cast<size_t>(b)] = revision_;
}

void TsdfMap::markAllChanged(uint64_t after) {
  revision_ = std::max(revision_, after) + 1;
  std::fill(block_revisions_.begin(), block_revisions_.end(), revision_);
}

std::vector<int32_t> TsdfMap::changedSince(uint64_t revision) const {
  std::vector<int32_t> out;
  for (size_t b = 0; b < block_revisions_.size(); ++b) {
    if (block_revisions_[b] > revision) out.push_back(static_cast<int32_t>(b));
  }
  return out;
}

size_t TsdfMap::removeBlocks(std::vector<int32_t> block_indices) {
  std::sort(block_indices.begin(), block_indices.end(), std::greater<>());
  block_indices.erase(std::unique(block_indices.begin(), block_indices.end()), block_indices.end());
  size_t refused = 0;
  const size_t before = keys_.size();
  if (!block_indices.empty()) ++revision_;
  // Highest first: the last block is never one still to be removed.
  for (const int32_t b : block_indices) {
    if (b < 0 || static_cast<size_t>(b) >= keys_.size()) continue;
    const size_t i = static_cast<size_t>(b);
    if (backing_ && backing_->put(keys_[i], block(i))) {
      elsewhere_.insert(keys_[i]);
    } else {
      ++refused;
      ++lost_in_backing_;
    }
    const size_t last = keys_.size() - 1;
    if (i != last) {
      block(i) = block(last);
      keys_[i] = keys_[last];
      block_revisions_[i] = revision_;  // moved: whoever follows indices reads it again
    }
    keys_.pop_back();
    block_revisions_.pop_back();
  }
  // Chunks no block uses go back to the system; slots beyond the blocks
  // hold old voxels until findOrAllocate clears them.
  const size_t chunks = (keys_.size() + kChunkBlocks - 1) / kChunkBlocks;
  if (chunks < chunks_.size()) {
    chunks_.resize(chunks);
    chunk_generation_.resize(chunks);
  }
  stale_end_ = std::min(std::max(stale_end_, before), chunks_.size() * kChunkBlocks);
  rehash(table_keys_.size());
  return refused;
}

void TsdfMap::clear() {
  elsewhere_.clear();
  chunks_.clear();
  chunk_generation_.clear();
  stale_end_ = 0;
  keys_.clear();
  block_revisions_.clear();
  ++revision_;
  rehash(1 << 12);
}

void TsdfMap::assignBlocks(const TsdfMap& map, const Eigen::AlignedBox3f& box_world) {
  params_ = map.params_;
  voxel_size_ = map.voxel_size_;
  truncation_ = map.truncation_;
  inv_voxel_size_ = map.inv_voxel_size_;
  inv_block_size_ = map.inv_block_size_;
  keys_.clear();
  block_revisions_.clear();
  revision_ = 0;
  std::fill(table_keys_.begin(), table_keys_.end(), 0);
  std::fill(table_values_.begin(), table_values_.end(), -1);
  // Chunks stay: every block allocated below is overwritten whole, and
  // the slots after them are cleared when allocated later.
  stale_end_ = 0;
  // An empty box copies nothing; one beyond 100 km is cut there (block
  // coordinates stay ints).
  constexpr float kWorld = 1e5f;
  if (!box_world.isEmpty() && box_world.min().allFinite() && box_world.max().allFinite()) {
    const BlockKey lo = map.blockOf(box_world.min().cwiseMax(-kWorld)), hi = map.blockOf(box_world.max().cwiseMin(kWorld));
    const double cells = (hi - lo + BlockKey::Ones()).cast<double>().prod();
    if (cells > static_cast<double>(map.blockCount())) {
      // Fewer blocks than cells: visit the blocks.
      for (size_t b = 0; b < map.blockCount(); ++b) {
        const BlockKey& k = map.key(b);
        if ((k.array() >= lo.array()).all() && (k.array() <= hi.array()).all()) {
          block(static_cast<size_t>(findOrAllocate(k))) = map.block(b);
        }
      }
    } else {
      for (int z = lo.z(); z <= hi.z(); ++z) {
        for (int y = lo.y(); y <= hi.y(); ++y) {
          for (int x = lo.x(); x <= hi.x(); ++x) {
            const int32_t b = map.find(BlockKey(x, y, z));
            if (b >= 0) block(static_cast<size_t>(findOrAllocate(BlockKey(x, y, z)))) = map.block(static_cast<size_t>(b));
          }
        }
      }
    }
  }
  stale_end_ = chunks_.size() * kChunkBlocks;
}

TsdfMap copyBlocks(const TsdfMap& map, const Eigen::AlignedBox3f& box_world) {
  TsdfMap out(map.params());
  out.assignBlocks(map, box_world);
  return out;
}

}  // namespace hxmap::alg
