// Sleeping until there is work, without polling and without missing the
// end: a Doorbell (a counter one thread waits on and others ring), and a
// LatestInbox (a LatestSlot with a doorbell and a close, the frontend's
// input).
//
// Threads: any thread rings; one thread (the owner) waits.
#pragma once

#include <atomic>
#include <cstdint>
#include <utility>

#include "hxmap/ring/latest_slot.hpp"

namespace hxmap::rt {

/// A counter a thread sleeps on until another thread rings it. The sleeper
/// reads the counter, looks for work, and only then waits on what it read,
/// so a ring in between wakes it at once:
///
///   while (!stopping) {
///     const uint32_t seen = bell.read();
///     if (takeWork()) { ...; continue; }
///     bell.wait(seen, stopping);
///   }
///
/// The stop flag is read again inside wait(), after the counter: whoever
/// stops sets the flag before ringing, so a thread that read the rung value
/// sees the flag and does not sleep. (Checked only at the top of the loop,
/// a stop between that check and the read of the counter is missed and the
/// thread sleeps forever.)
class Doorbell {
 public:
  uint32_t read() const { return count_.load(std::memory_order_acquire); }
  void ring() {
    count_.fetch_add(1, std::memory_order_release);
    count_.notify_all();
  }
  /// Sleeps until rung after `seen` was read, unless `stopping` is set.
  void wait(uint32_t seen, const std::atomic<bool>& stopping) const {
    if (!stopping.load()) count_.wait(seen, std::memory_order_acquire);
  }

 private:
  std::atomic<uint32_t> count_{0};  // wraps; only "changed since read" matters
};

/// The newest value from one producer to one consumer, who sleeps until
/// there is one; the producer closes it when no more will come.
template <typename T>
class LatestInbox {
 public:
  /// Producer. True when an unread value was replaced (a drop).
  bool publish(T&& value) {
    const bool replaced = slot_.publish(std::move(value));
    bell_.ring();
    return replaced;
  }
  /// Producer: no more values.
  void close() {
    closed_.store(true);
    bell_.ring();
  }
  /// Consumer: blocks for the next value; false once closed and empty.
  bool take(T& out) {
    while (true) {
      const uint32_t seen = bell_.read();
      if (slot_.take(out)) return true;
      // A value published after the look above and before the close is
      // taken here, not lost.
      if (closed_.load()) return slot_.take(out);
      bell_.wait(seen, closed_);
    }
  }

 private:
  LatestSlot<T> slot_;
  Doorbell bell_;
  std::atomic<bool> closed_{false};
};

}  // namespace hxmap::rt
