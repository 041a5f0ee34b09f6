// Bounded lock-free single-producer/single-consumer ring: the hand-off
// between runtime threads (sensor -> frontend, frontend -> refinement and
// pose feedback, and back).
//
// Threads: exactly one producer thread calls tryPush/emplace; exactly one
// consumer thread calls tryPop/front/popLatest. capacity() may be called
// from anywhere; sizeApprox() from anywhere, as a hint. Construction and
// destruction happen while neither side runs.
//
// DESIGN (after rigtorp/SPSCQueue): slots are allocated once, at
// construction; push and pop never allocate. The write and read indices sit
// on their own cache lines, each next to the owning side's cached copy of the
// other side's index, so a side touches the other's line only when its cached
// view says full (producer) or empty (consumer). One slot is left empty to
// tell full from empty. Elements are constructed in place and destroyed on
// pop.
//
// Full policy is the caller's: tryPush returns false and the producer counts
// the rejection. For "always work on the newest" (sensor frames), the
// consumer skips ahead with popLatest, which pops everything queued, keeps
// the newest and reports how many stale ones it dropped: only the consumer
// pops in an SPSC ring, so dropping the oldest is the consumer's job.
#pragma once

#include <atomic>
#include <cstddef>
#include <memory>
#include <new>
#include <stdexcept>
#include <type_traits>
#include <utility>

namespace hxmap::rt {

inline constexpr size_t kCacheLine = 64;

template <typename T>
class SpscRing {
 public:
  /// Holds up to `capacity` elements (>= 1).
  explicit SpscRing(size_t capacity) : slots_(capacity + 1) {
    if (capacity < 1) throw std::invalid_argument("SpscRing: capacity must be at least 1");
    storage_ = static_cast<Slot*>(::operator new[](slots_ * sizeof(Slot), std::align_val_t{alignof(Slot)}));
  }
  ~SpscRing() {
    clear();
    ::operator delete[](storage_, std::align_val_t{alignof(Slot)});
  }
  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;

  size_t capacity() const { return slots_ - 1; }

  /// Producer. Constructs the element in place; false (nothing constructed)
  /// when the ring is full.
  template <typename... Args>
  [[nodiscard]] bool emplace(Args&&... args) {
    const size_t write = write_.index.load(std::memory_order_relaxed);
    const size_t next = write + 1 == slots_ ? 0 : write + 1;
    if (next == write_.cached_other) {
      write_.cached_other = read_.index.load(std::memory_order_acquire);
      if (next == write_.cached_other) return false;
    }
    new (&storage_[write].value) T(std::forward<Args>(args)...);
    write_.index.store(next, std::memory_order_release);
    return true;
  }
  [[nodiscard]] bool tryPush(const T& value) { return emplace(value); }
  [[nodiscard]] bool tryPush(T&& value) { return emplace(std::move(value)); }

  /// Consumer. Moves the oldest element into `out`; false when empty.
  [[nodiscard]] bool tryPop(T& out) {
    T* f = front();
    if (f == nullptr) return false;
    out = std::move(*f);
    pop();
    return true;
  }

  /// Consumer. Pops everything queued into `out`, keeping the newest; the
  /// number of older elements discarded goes to `skipped`. False when empty.
  [[nodiscard]] bool popLatest(T& out, size_t& skipped) {
    skipped = 0;
    if (!tryPop(out)) return false;
    while (T* f = front()) {
      out = std::move(*f);
      pop();
      ++skipped;
    }
    return true;
  }

  /// Consumer. The oldest element, or nullptr when empty; valid until pop().
  T* front() {
    const size_t read = read_.index.load(std::memory_order_relaxed);
    if (read == read_.cached_other) {
      read_.cached_other = write_.index.load(std::memory_order_acquire);
      if (read == read_.cached_other) return nullptr;
    }
    return &storage_[read].value;
  }
  /// Consumer. Destroys the oldest element; the ring must not be empty.
  void pop() {
    const size_t read = read_.index.load(std::memory_order_relaxed);
    storage_[read].value.~T();
    read_.index.store(read + 1 == slots_ ? 0 : read + 1, std::memory_order_release);
  }

  /// Elements queued, as seen from the calling thread (a hint under concurrency).
  size_t sizeApprox() const {
    const size_t w = write_.index.load(std::memory_order_acquire), r = read_.index.load(std::memory_order_acquire);
    return w >= r ? w - r : w + slots_ - r;
  }
  bool emptyApprox() const { return sizeApprox() == 0; }

 private:
  union Slot {
    Slot() {}
    ~Slot() {}
    T value;
  };
  struct alignas(kCacheLine) Side {
    std::atomic<size_t> index{0};
    size_t cached_other = 0;  ///< this side's last view of the other's index
  };
  /// Consumer-side destruction of what is left (single-threaded: destructor).
  void clear() {
    while (front() != nullptr) pop();
  }

  const size_t slots_;  // read-only after construction: shared freely
  Slot* storage_ = nullptr;
  Side write_;  ///< producer's line
  Side read_;   ///< consumer's line (alignment pads it to a full line)
};

}  // namespace hxmap::rt
