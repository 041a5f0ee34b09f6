// Checkpoints of a live run: the frontend thread hands over a copy of the
// map (RealtimeOptions::on_checkpoint); this thread meshes it and writes
// the mesh and trajectory into the run's folder, so SIGKILL or the OOM
// killer loses at most one checkpoint interval of the map.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>

#include "hxmap/realtime/realtime.hpp"

namespace hxmap::rt {

class CheckpointWriter {
 public:
  /// `write` runs on the writer's thread (hx-checkpoint, at `nice`).
  CheckpointWriter(std::function<void(const MapCheckpoint&)> write, int nice);
  /// Finishes the checkpoint under way (a newer pending one is dropped).
  ~CheckpointWriter();
  CheckpointWriter(const CheckpointWriter&) = delete;
  CheckpointWriter& operator=(const CheckpointWriter&) = delete;

  /// Any thread, never blocks for long: a checkpoint not yet started is
  /// replaced by this newer one.
  void offer(MapCheckpoint&& checkpoint);
  uint64_t written() const;

 private:
  void run();

  std::function<void(const MapCheckpoint&)> write_;
  int nice_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::optional<MapCheckpoint> pending_;
  bool stop_ = false;
  uint64_t written_ = 0;
  std::thread thread_;
};

}  // namespace hxmap::rt
