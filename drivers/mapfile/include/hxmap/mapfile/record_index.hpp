// The block store's index: where each block's record is in the store file,
// by packed block key. An open-addressing table of 24-byte slots (linear
// probing, deletion by shifting back), at most 70 % full.
//
// DESIGN: a long run holds hundreds of thousands of blocks on disk, and
// the index is what stays in memory for each. A node-based hash map took
// 56-72 bytes a record (node, allocator header, bucket); this takes 34 to
// 69 (slots 35-70 % full), and no allocation per record.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

namespace hxmap::drv {

class RecordIndex {
 public:
  struct Record {
    uint64_t offset = 0;
    uint32_t stored = 0;  ///< bytes in the file (below 2^31)
    uint32_t crc = 0;
    bool seen_through = false;
  };

  std::optional<Record> find(uint64_t key) const {
    if (size_ == 0) return std::nullopt;
    const size_t s = slotOf(key);
    if (slots_[s].key1 == 0) return std::nullopt;
    const Slot& slot = slots_[s];
    return Record{slot.offset, slot.stored_seen & kStoredMask, slot.crc, (slot.stored_seen & kSeenBit) != 0};
  }
  bool contains(uint64_t key) const { return size_ > 0 && slots_[slotOf(key)].key1 != 0; }
  /// Inserts or replaces.
  void set(uint64_t key, const Record& r) {
    if ((size_ + 1) * 10 > slots_.size() * 7) rehash(slots_.empty() ? 1024 : slots_.size() * 2);
    Slot& slot = slots_[slotOf(key)];
    if (slot.key1 == 0) ++size_;
    slot = Slot{key + 1, r.offset, (r.stored & kStoredMask) | (r.seen_through ? kSeenBit : 0), r.crc};
  }
  /// Moves a record that is still at `from` to `to` (compaction).
  void moveIfAt(uint64_t key, uint64_t from, uint64_t to) {
    if (size_ == 0) return;
    Slot& slot = slots_[slotOf(key)];
    if (slot.key1 != 0 && slot.offset == from) slot.offset = to;
  }
  bool erase(uint64_t key) {
    if (size_ == 0) return false;
    const size_t mask = slots_.size() - 1;
    size_t hole = slotOf(key);
    if (slots_[hole].key1 == 0) return false;
    slots_[hole] = Slot{};
    --size_;
    // Shift back the slots after the hole that probed past it.
    for (size_t s = (hole + 1) & mask; slots_[s].key1 != 0; s = (s + 1) & mask) {
      const size_t home = homeOf(slots_[s].key1 - 1);
      // Movable when its home is not within (hole, s] cyclically.
      const bool stays = hole <= s ? (home > hole && home <= s) : (home > hole || home <= s);
      if (stays) continue;
      slots_[hole] = slots_[s];
      slots_[s] = Slot{};
      hole = s;
    }
    if (slots_.size() > 1024 && size_ * 8 < slots_.size()) rehash(slots_.size() / 2);
    return true;
  }
  size_t size() const { return size_; }
  void clear() {
    slots_.clear();
    slots_.shrink_to_fit();
    size_ = 0;
  }
  size_t memoryBytes() const { return slots_.capacity() * sizeof(Slot); }
  /// Calls f(key, record) for every record.
  template <class F>
  void forEach(F&& f) const {
    for (const Slot& slot : slots_) {
      if (slot.key1 != 0) {
        f(slot.key1 - 1,
          Record{slot.offset, slot.stored_seen & kStoredMask, slot.crc, (slot.stored_seen & kSeenBit) != 0});
      }
    }
  }

 private:
  static constexpr uint32_t kSeenBit = 1u << 31, kStoredMask = kSeenBit - 1;
  struct Slot {
    uint64_t key1 = 0;  ///< key + 1; 0: empty
    uint64_t offset = 0;
    uint32_t stored_seen = 0;
    uint32_t crc = 0;
  };
  size_t homeOf(uint64_t key) const {
    uint64_t h = key * 0x9E3779B97F4A7C15ULL;
    h ^= h >> 29;
    return static_cast<size_t>(h) & (slots_.size() - 1);
  }
  /// The key's slot, or the empty slot where it would go.
  size_t slotOf(uint64_t key) const {
    const size_t mask = slots_.size() - 1;
    size_t s = homeOf(key);
    while (slots_[s].key1 != 0 && slots_[s].key1 != key + 1) s = (s + 1) & mask;
    return s;
  }
  void rehash(size_t capacity) {
    std::vector<Slot> old;
    old.swap(slots_);
    slots_.assign(capacity, Slot{});
    const size_t mask = capacity - 1;
    for (const Slot& slot : old) {
      if (slot.key1 == 0) continue;
      size_t s = homeOf(slot.key1 - 1);
      while (slots_[s].key1 != 0) s = (s + 1) & mask;
      slots_[s] = slot;
    }
  }

  std::vector<Slot> slots_;
  size_t size_ = 0;
};

}  // namespace hxmap::drv
