// Shared by the DDS test and benchmark: the loopback-only Cyclone DDS
// profile, and polling for a condition with a deadline (discovery and
// delivery take a moment on any machine).
#pragma once

#include <chrono>
#include <thread>

namespace hxmap {

/// CYCLONEDDS_URI for config/cyclonedds-loopback.xml in the source tree.
constexpr const char* kLoopbackDdsUri = "file://" HXMAP_SOURCE_DIR "/config/cyclonedds-loopback.xml";

/// Polls `pred` every 10 ms until it holds or `timeout_s` passes; its last value.
template <class Pred>
bool waitFor(Pred pred, double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return pred();
}

}  // namespace hxmap
