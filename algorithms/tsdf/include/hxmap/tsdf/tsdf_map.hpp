// Voxel-hashed TSDF: blocks of 8^3 voxels, allocated only in the truncation
// band of observed depth, found through an open-addressing hash of block
// coordinates. Voxel (i, j, k) has its center at ((i, j, k) + 0.5) * voxel_size
// in the world frame.
//
// Thread safety: not synchronized. One writer (the frontend) mutates the map;
// readers work on their own copy (see copyBlocks, snapshot) or run between
// writes.
#pragma once

#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "hxmap/tsdf/block_key_set.hpp"
#include "hxmap/tsdf/params.hpp"

namespace hxmap::alg {

constexpr int kBlockSide = 8;  // voxel -> block by >> 3 and & 7 below
constexpr int kBlockVoxels = kBlockSide * kBlockSide * kBlockSide;

struct VoxelColor {
  uint8_t r = 0, g = 0, b = 0, flags = 0;
};

/// VoxelColor::flags: refinement found free space here that fusion had
/// filled (light from other views passed through the voxel). Fusion then
/// skips observations that put the voxel more than a voxel behind a
/// surface (see integrate.hpp); one that puts it at a surface clears the
/// flag.
constexpr uint8_t kVoxelSeenThrough = 1;

/// Running statistics (Welford) of the truncated SDF observations a voxel
/// received near the surface, from which the UF quality indicator takes
/// sigma_TSDF.
struct VoxelStats {
  uint32_t updates = 0;
  float mean_m = 0.0f;
  float m2 = 0.0f;  ///< sum of squared deviations, m^2
  float variance() const { return updates > 1 ? m2 / static_cast<float>(updates - 1) : 0.0f; }
};

/// Fused signed distance and weight (summed confidence, capped at
/// max_weight) of one voxel.
struct VoxelGeometry {
  float sdf_m = 0.0f;
  float weight = 0.0f;
};

/// 8^3 voxels stored as three arrays. DESIGN: the hot loops (raycast
/// marching and trilinear samples, the geometry pass of fusion, meshing)
/// read only sdf and weight, so those sit together in 4 KiB per block
/// instead of being interleaved with color and statistics (24 bytes per
/// voxel as an array of structs): one cache line holds a row of 8 voxels,
/// sdf next to its weight, so a trilinear sample touches 4 lines, not 8.
struct VoxelBlock {
  VoxelGeometry geo[kBlockVoxels] = {};
  VoxelColor color[kBlockVoxels] = {};
  VoxelStats stats[kBlockVoxels] = {};
  bool seen_through = false;  ///< some voxel may carry kVoxelSeenThrough
  static int index(int x, int y, int z) { return (z * kBlockSide + y) * kBlockSide + x; }
};

/// One voxel's values, copied out of its block (see TsdfMap::voxel).
struct Voxel {
  float sdf_m = 0.0f;
  float weight = 0.0f;
  VoxelColor color;
  VoxelStats stats;
};

using BlockKey = Eigen::Vector3i;

/// A block key as one integer (21 bits per axis), for hash maps and sets.
inline uint64_t packBlockKey(const BlockKey& k) {
  return (static_cast<uint64_t>(k.x() + (1 << 20)) << 42) | (static_cast<uint64_t>(k.y() + (1 << 20)) << 21) |
         static_cast<uint64_t>(k.z() + (1 << 20));
}
inline BlockKey unpackBlockKey(uint64_t p) {
  const uint64_t mask = (1u << 21) - 1;
  return {static_cast<int>((p >> 42) & mask) - (1 << 20), static_cast<int>((p >> 21) & mask) - (1 << 20),
          static_cast<int>(p & mask) - (1 << 20)};
}

/// Memory in use, for reports.
struct MapMemory {
  size_t blocks = 0;
  size_t bytes = 0;  ///< voxel storage + hash table
};

/// Where blocks go when they leave memory (a memory budget): a block store
/// on disk in a run (drivers/mapfile). The map's single writer calls it.
class BlockBacking {
 public:
  virtual ~BlockBacking() = default;
  /// Keeps the block; false when it could not (the block is then lost).
  virtual bool put(const BlockKey& key, const VoxelBlock& block) = 0;
  /// The block's voxels into `out`, and forgets it; false when it holds
  /// none for `key` or could not read it back.
  virtual bool take(const BlockKey& key, VoxelBlock& out) = 0;
  /// Forgets every block (the map was rebuilt without them).
  virtual void clear() = 0;
  /// A hint that these blocks are wanted soon (the predicted view),
  /// replacing the previous hint: a backing that reads slowly may start
  /// reading them in the background. take() is still how they come back.
  virtual void prefetch(const std::vector<BlockKey>& keys) { (void)keys; }
  /// False when take(key) would wait on a read that has not been done yet.
  virtual bool ready(const BlockKey& key) const {
    (void)key;
    return true;
  }
};

class TsdfMap {
 public:
  explicit TsdfMap(const TsdfParams& params);
  TsdfMap(const TsdfMap& other);
  TsdfMap& operator=(const TsdfMap& other);
  TsdfMap(TsdfMap&&) noexcept = default;
  TsdfMap& operator=(TsdfMap&&) noexcept = default;

  const TsdfParams& params() const { return params_; }
  float voxelSize() const { return voxel_size_; }
  float invVoxelSize() const { return inv_voxel_size_; }
  float blockSize() const { return voxel_size_ * kBlockSide; }
  float truncation() const { return truncation_; }

  size_t blockCount() const { return keys_.size(); }
  const BlockKey& key(size_t block_index) const { return keys_[block_index]; }
  /// A block to write: a chunk still shared with a snapshot is copied
  /// first. Writers in parallel call prepareWrites(their blocks) before.
  VoxelBlock& block(size_t block_index) {
    const size_t c = block_index / kChunkBlocks;
    if (chunk_generation_[c] < shared_below_) [[unlikely]]
      ownChunk(c);
    return chunks_[c][block_index % kChunkBlocks];
  }
  const VoxelBlock& block(size_t block_index) const {
    return chunks_[block_index / kChunkBlocks][block_index % kChunkBlocks];
  }
  /// Makes block(i) for these blocks free of copying, so that threads can
  /// then write them in parallel (one thread per block).
  void prepareWrites(const std::vector<int32_t>& block_indices);

  /// A copy that shares this map's voxel memory: O(blocks) in keys and
  /// table, none in voxels. While the snapshot lives, the chunks of blocks
  /// (kChunkBlocks each) are shared until either map writes into one,
  /// which copies that chunk for itself (copy on write); once every
  /// snapshot is gone, this map writes in place again. For a reader on
  /// another thread that needs the whole map at one instant (a checkpoint)
  /// while this map goes on. The snapshot may be destroyed on any thread.
  TsdfMap snapshot();
  /// Chunks copied because a snapshot shared them, since construction.
  uint64_t chunksCopiedOnWrite() const { return chunks_copied_on_write_; }

  /// Change tracking, for publishing map updates: every writer (integration,
  /// patches) calls markChanged on the blocks it wrote, which stamps them
  /// with a new map revision. changedSince(r) lists the blocks written after
  /// revision r was current. Allocation alone is not a change (a new block
  /// holds no surface until something is fused into it).
  uint64_t revision() const { return revision_; }
  void markChanged(const std::vector<int32_t>& block_indices);
  std::vector<int32_t> changedSince(uint64_t revision) const;
  /// Every block written anew, at a revision after `after` (a map that
  /// replaces another: whoever followed the old one's revisions sees every
  /// block of this one as changed).
  void markAllChanged(uint64_t after);

  /// Index of the block, or -1 when not allocated. Inline: it is on every
  /// hot path (raycast, trilinear sampling, meshing).
  int32_t find(const BlockKey& key) const {
    const uint64_t packed = pack(key) + 1;
    const size_t mask = table_keys_.size() - 1;
    for (size_t s = slotOf(packed, mask);; s = (s + 1) & mask) {
      const uint64_t k = table_keys_[s];
      if (k == packed) return table_values_[s];
      if (k == 0) return -1;
    }
  }
  /// Index of the block, allocating it (voxels zero-weight) when missing;
  /// a block held by the backing (removeBlocks) comes back with its voxels.
  /// Blocks move only in clear(), removeBlocks() and the first write into
  /// their chunk after a snapshot().
  int32_t findOrAllocate(const BlockKey& key);

  /// Memory budget: the backing that removed blocks go to and come back
  /// from. Not owned; not copied with the map (a copy is a snapshot for a
  /// reader, which must not touch the backing).
  void setBacking(BlockBacking* backing) { backing_ = backing; }
  /// Moves the blocks out of memory into the backing. The last blocks move
  /// into the freed slots: their indices change (they are marked changed),
  /// keys do not. Returns how many the backing refused (lost).
  size_t removeBlocks(std::vector<int32_t> block_indices);
  /// Blocks held by the backing (part of the map, not in memory). Copies
  /// and snapshots know them too, without the backing to bring them back.
  bool heldElsewhere(const BlockKey& key) const { return elsewhere_.contains(key); }
  const BlockKeySet& blocksElsewhere() const { return elsewhere_; }
  /// Blocks the backing gave back, and those it failed to.
  uint64_t blocksTakenBack() const { return taken_back_; }
  uint64_t blocksLostInBacking() const { return lost_in_backing_; }

  BlockKey blockOf(const Eigen::Vector3f& p_world) const {
    const Eigen::Vector3f q = p_world * inv_block_size_;
    return {static_cast<int>(std::floor(q.x())), static_cast<int>(std::floor(q.y())),
            static_cast<int>(std::floor(q.z()))};
  }
  /// Global voxel coordinates of the voxel containing p.
  Eigen::Vector3i voxelOf(const Eigen::Vector3f& p_world) const {
    const Eigen::Vector3f q = p_world * inv_voxel_size_;
    return {static_cast<int>(std::floor(q.x())), static_cast<int>(std::floor(q.y())),
            static_cast<int>(std::floor(q.z()))};
  }
  Eigen::Vector3f voxelCenter(const Eigen::Vector3i& voxel) const {
    return (voxel.cast<float>() + Eigen::Vector3f::Constant(0.5f)) * voxel_size_;
  }
  /// Voxel by global coordinates; false when its block is not allocated.
  bool voxel(const Eigen::Vector3i& global, Voxel& out) const;
  /// The block holding a global voxel and the voxel's index in it, or
  /// nullptr when not allocated.
  const VoxelBlock* blockOfVoxel(const Eigen::Vector3i& global, int& index) const {
    const BlockKey key(global.x() >> 3, global.y() >> 3, global.z() >> 3);  // floor division by 8
    const int32_t b = find(key);
    if (b < 0) return nullptr;
    index = VoxelBlock::index(global.x() & 7, global.y() & 7, global.z() & 7);
    return &block(static_cast<size_t>(b));
  }

  /// Trilinear SDF at p from the 8 surrounding voxel centers; false when any
  /// of them is unallocated or has weight < min_weight.
  bool sample(const Eigen::Vector3f& p_world, float min_weight, float& sdf_m) const;
  bool sampleColor(const Eigen::Vector3f& p_world, Eigen::Vector3f& rgb) const;

  MapMemory memory() const;
  /// Blocks are stored, and counted in memory(), in chunks of this many:
  /// removing blocks frees memory a whole chunk at a time.
  static constexpr size_t chunkBlocks() { return kChunkBlocks; }
  void clear();
  /// Makes this map what copyBlocks(map, box_world) returns (same
  /// parameters), in this map's block memory: no allocation while it has
  /// held as many blocks before.
  void assignBlocks(const TsdfMap& map, const Eigen::AlignedBox3f& box_world);

 private:
  static uint64_t pack(const BlockKey& k) { return packBlockKey(k); }
  static size_t slotOf(uint64_t packed, size_t mask) {
    uint64_t h = packed * 0x9E3779B97F4A7C15ULL;
    h ^= h >> 29;
    return static_cast<size_t>(h) & mask;
  }
  void rehash(size_t capacity);
  void ownChunk(size_t chunk);
  void addChunk();

  TsdfParams params_;
  float voxel_size_, truncation_;
  float inv_voxel_size_, inv_block_size_;
  // DESIGN: blocks live in fixed chunks of kChunkBlocks, not one growing
  // vector: growing a vector of 24 KiB blocks copied the whole map at every
  // doubling, a stall of tens of ms on the frontend thread for a map of a
  // few thousand blocks (a deadline miss), and reserved up to twice the
  // memory in use. A chunk is 384 KiB; at most one is partly used.
  static constexpr size_t kChunkBlocks = 16;
  std::vector<std::shared_ptr<VoxelBlock[]>> chunks_;
  /// A chunk is shared with a snapshot while its generation is below
  /// shared_below_: snapshot() raises that past every chunk's, and a chunk
  /// copied or added takes the map's generation, above it. Once the
  /// snapshots taken are all gone (snapshots_alive_, decremented with
  /// release ordering after the reader's last access, read with acquire
  /// here), shared_below_ drops to 0: writes go in place again.
  std::vector<uint64_t> chunk_generation_;
  uint64_t generation_ = 0, shared_below_ = 0;
  uint64_t chunks_copied_on_write_ = 0;
  /// Snapshots of this map alive (in this map); in a snapshot, its
  /// source's counter, held until the snapshot is destroyed.
  struct SnapshotHold {
    std::shared_ptr<std::atomic<int>> count;
    SnapshotHold() = default;
    SnapshotHold(const SnapshotHold&) {}  // a copy of a map holds nothing
    SnapshotHold& operator=(const SnapshotHold&) { return *this; }
    SnapshotHold(SnapshotHold&& o) noexcept : count(std::move(o.count)) {}
    SnapshotHold& operator=(SnapshotHold&& o) noexcept {
      release();
      count = std::move(o.count);
      return *this;
    }
    ~SnapshotHold() { release(); }
    void release() {
      if (count) count->fetch_sub(1, std::memory_order_release);
      count.reset();
    }
  };
  std::shared_ptr<std::atomic<int>> snapshots_alive_;
  SnapshotHold hold_;
  /// Block slots from blockCount() up to this hold another map's voxels
  /// (left by assignBlocks): findOrAllocate clears them.
  size_t stale_end_ = 0;
  std::vector<BlockKey> keys_;
  std::vector<uint64_t> block_revisions_;  ///< revision of each block's last write
  uint64_t revision_ = 0;
  std::vector<uint64_t> table_keys_;  ///< packed key + 1, 0 = empty slot
  std::vector<int32_t> table_values_;
  BlockBacking* backing_ = nullptr;
  BlockKeySet elsewhere_;  ///< blocks in the backing
  uint64_t taken_back_ = 0, lost_in_backing_ = 0;
};

/// A map holding copies of the allocated blocks of `map` that overlap
/// `box_world` (same parameters): a snapshot for a reader on another thread.
TsdfMap copyBlocks(const TsdfMap& map, const Eigen::AlignedBox3f& box_world);

/// Block lookups through a small direct-mapped cache, for runs of nearby
/// queries (one ray, one neighbourhood): the 8 blocks around a corner fall
/// in distinct slots. One per thread; valid while the map is not modified.
class BlockCache {
 public:
  explicit BlockCache(const TsdfMap& map) : map_(&map) {}
  const VoxelBlock* get(const BlockKey& key) {
    Entry& e = entries_[(key.x() & 1) | ((key.y() & 1) << 1) | ((key.z() & 1) << 2)];
    if (!(e.key == key)) {
      e.key = key;
      const int32_t b = map_->find(key);
      e.block = b >= 0 ? &map_->block(b) : nullptr;
    }
    return e.block;
  }
  /// The block holding a global voxel and the voxel's index in it.
  const VoxelBlock* blockOfVoxel(const Eigen::Vector3i& g, int& index) {
    index = VoxelBlock::index(g.x() & 7, g.y() & 7, g.z() & 7);
    return get(BlockKey(g.x() >> 3, g.y() >> 3, g.z() >> 3));
  }
  /// Trilinear SDF at p from the 8 surrounding voxel centers; false when any
  /// of them is unallocated or has weight < min_weight (or none).
  bool sample(const Eigen::Vector3f& p_world, float min_weight, float& sdf_m);
  bool sampleColor(const Eigen::Vector3f& p_world, Eigen::Vector3f& rgb);
  /// One gather of the 8 voxels around p: the trilinear SDF, its exact
  /// gradient (per meter, the trilinear's derivative, not a finite
  /// difference) and the trilinear color (0..255).
  bool sampleWithGradient(const Eigen::Vector3f& p_world, float min_weight, float& sdf_m, Eigen::Vector3f& gradient,
                          Eigen::Vector3f& rgb);
  /// The same; the color only when rgb is not null.
  bool sampleWithGradient(const Eigen::Vector3f& p_world, float min_weight, float& sdf_m, Eigen::Vector3f& gradient,
                          Eigen::Vector3f* rgb);

 private:
  struct Entry {
    BlockKey key{std::numeric_limits<int>::min(), 0, 0};
    const VoxelBlock* block = nullptr;
  };
  const TsdfMap* map_;
  Entry entries_[8];
};

/// floor() for floats well inside the int range, without a libm call.
inline int floorToInt(float x) {
  const int i = static_cast<int>(x);
  return i - (x < static_cast<float>(i));
}

}  // namespace hxmap::alg
