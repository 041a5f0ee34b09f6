// A set of block keys, kept as one bitmap per cube of 8^3 blocks (a
// "region": 64 bytes of bits). It holds the blocks a map under a memory
// budget moved out (TsdfMap::blocksElsewhere).
//
// DESIGN: a long run moves out hundreds of thousands of blocks, and the
// frontend looks, every frame, for those in the camera's view. A hash set
// of keys cost about 40 bytes a block (node, bucket, allocator) and a
// walk over every key a frame, a cost that grew with the path. Blocks
// moved out lie on surfaces, dozens to a region: here a block costs
// about a bit and a half, and a query tests regions first (the regions
// out of view are skipped whole).
#pragma once

#include <bit>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

namespace hxmap::alg {

class BlockKeySet {
 public:
  static constexpr int kRegionSide = 8;  ///< blocks per side of a region

  bool insert(const Eigen::Vector3i& key) {
    Region& region = regions_[regionKey(key)];
    uint64_t& word = region.words[bit(key) >> 6];
    const uint64_t mask = uint64_t{1} << (bit(key) & 63);
    if (word & mask) return false;
    word |= mask;
    ++region.count;
    ++size_;
    return true;
  }
  bool erase(const Eigen::Vector3i& key) {
    const auto it = regions_.find(regionKey(key));
    if (it == regions_.end()) return false;
    uint64_t& word = it->second.words[bit(key) >> 6];
    const uint64_t mask = uint64_t{1} << (bit(key) & 63);
    if (!(word & mask)) return false;
    word &= ~mask;
    --size_;
    if (--it->second.count == 0) regions_.erase(it);
    return true;
  }
  bool contains(const Eigen::Vector3i& key) const {
    const auto it = regions_.find(regionKey(key));
    return it != regions_.end() && (it->second.words[bit(key) >> 6] >> (bit(key) & 63) & 1) != 0;
  }
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  void clear() {
    regions_.clear();
    size_ = 0;
  }
  /// Bytes held (regions, their nodes and the table's buckets).
  size_t memoryBytes() const {
    return regions_.size() * (sizeof(Region) + 2 * sizeof(void*) + sizeof(uint64_t)) +
           regions_.bucket_count() * sizeof(void*);
  }

  /// Calls f(key) for the keys of every region whose first block
  /// `region_min` (the region spans kRegionSide blocks from there on each
  /// axis) passes wanted(region_min); all when wanted always says yes.
  template <class Wanted, class F>
  void forEachIn(Wanted&& wanted, F&& f) const {
    for (const auto& [packed, region] : regions_) {
      const Eigen::Vector3i lo = regionMin(packed);
      if (!wanted(lo)) continue;
      for (int w = 0; w < kWords; ++w) {
        for (uint64_t word = region.words[w]; word != 0; word &= word - 1) {
          const int b = w * 64 + std::countr_zero(word);
          f(Eigen::Vector3i(lo.x() + (b & 7), lo.y() + ((b >> 3) & 7), lo.z() + (b >> 6)));
        }
      }
    }
  }
  template <class F>
  void forEach(F&& f) const {
    forEachIn([](const Eigen::Vector3i&) { return true; }, f);
  }
  std::vector<Eigen::Vector3i> keys() const {
    std::vector<Eigen::Vector3i> out;
    out.reserve(size_);
    forEach([&](const Eigen::Vector3i& k) { out.push_back(k); });
    return out;
  }

 private:
  static constexpr int kWords = kRegionSide * kRegionSide * kRegionSide / 64;
  struct Region {
    uint64_t words[kWords] = {};
    uint32_t count = 0;
  };
  // Region coordinates (block >> 3 per axis, 21 bits each) packed in one
  // integer; a block's bit is its place in the region, x fastest.
  static uint64_t regionKey(const Eigen::Vector3i& k) {
    const uint64_t m = (uint64_t{1} << 21) - 1;
    return ((static_cast<uint64_t>(k.x() >> 3) & m) << 42) | ((static_cast<uint64_t>(k.y() >> 3) & m) << 21) |
           (static_cast<uint64_t>(k.z() >> 3) & m);
  }
  static Eigen::Vector3i regionMin(uint64_t packed) {
    // Sign-extend each 21-bit field back to the region coordinate.
    const auto field = [](uint64_t v) { return static_cast<int>(static_cast<int64_t>(v << 43) >> 43); };
    return Eigen::Vector3i(field(packed >> 42), field(packed >> 21), field(packed)) * kRegionSide;
  }
  static int bit(const Eigen::Vector3i& k) { return ((k.z() & 7) << 6) | ((k.y() & 7) << 3) | (k.x() & 7); }

  std::unordered_map<uint64_t, Region> regions_;
  size_t size_ = 0;
};

}  // namespace hxmap::alg
