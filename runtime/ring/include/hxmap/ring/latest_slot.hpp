// Lock-free single-producer/single-consumer "latest value" hand-off (a triple
// buffer): the sensor -> frontend link, where only the newest frame matters.
//
// Threads: one producer calls publish(); one consumer calls take().
//
// DESIGN: an SpscRing cannot drop its oldest element from the producer side
// (only the consumer pops), so during a burst that fills the ring the
// newest frames would be the ones rejected. Here the producer writes into
// its own buffer and swaps it with the shared middle one; if the middle still
// held an unread value, that older value is dropped and publish() says so,
// for the producer to count. The consumer swaps the middle with its own
// buffer when a new value is flagged. No allocation after construction; T is
// moved, never copied, and three T live for the slot's lifetime.
#pragma once

#include <atomic>
#include <cstdint>
#include <utility>

namespace hxmap::rt {

template <typename T>
class LatestSlot {
 public:
  LatestSlot() = default;
  LatestSlot(const LatestSlot&) = delete;
  LatestSlot& operator=(const LatestSlot&) = delete;

  /// Producer. Makes `value` the newest; true when it replaced a value the
  /// consumer had not taken (a dropped frame).
  bool publish(T&& value) {
    buffers_[back_] = std::move(value);
    const uint8_t previous = middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = previous & kIndex;
    return (previous & kFresh) != 0;
  }

  /// Consumer. Moves the newest value into `out`; false when nothing new
  /// has been published since the last take.
  bool take(T& out) {
    if ((middle_.load(std::memory_order_acquire) & kFresh) == 0) return false;
    const uint8_t previous = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = previous & kIndex;
    out = std::move(buffers_[front_]);
    return true;
  }

 private:
  static constexpr uint8_t kIndex = 0x3, kFresh = 0x4;
  T buffers_[3]{};
  alignas(64) std::atomic<uint8_t> middle_{2};
  alignas(64) uint8_t back_ = 0;   ///< producer's buffer
  alignas(64) uint8_t front_ = 1;  ///< consumer's buffer
};

}  // namespace hxmap::rt
