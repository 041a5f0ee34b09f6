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
#include <unordered_map>

#include "hxmap/realtime/realtime.hpp"
#include "hxmap/tsdf/map_regions.hpp"

namespace hxmap::rt {

/// The mesh a checkpoint writes. Without a memory budget, the map's mesh
/// with the refined regions' detail. Under a budget the snapshot lacks the
/// blocks moved out of memory: the mesh is then kept per region (a cube of
/// region_blocks TSDF blocks a side, as map updates are published), and a
/// region is meshed again when a block it reads changed or moved out since
/// the last checkpoint, its blocks out of memory read from the block store
/// (`read_elsewhere`, on this thread). A region with a block that did not
/// read back keeps its last mesh (or, never meshed, gets what was read)
/// and is meshed again at the next checkpoint. The refined detail is left
/// out under a budget. One thread.
class CheckpointMesher {
 public:
  using ReadElsewhere = alg::BlockReader;
  CheckpointMesher(const alg::MeshParams& params, ReadElsewhere read_elsewhere, int region_blocks = 4);
  /// Without a budget: the map's hybrid mesh, nothing kept.
  explicit CheckpointMesher(const alg::MeshParams& params);
  alg::TriangleMesh mesh(const MapCheckpoint& checkpoint);
  /// Regions whose mesh is older than their blocks (a block did not read back).
  size_t regionsWaiting() const { return waiting_.size(); }
  /// Blocks read from the block store, and those that did not read back.
  uint64_t blocksRead() const { return blocks_read_; }
  uint64_t blocksUnread() const { return blocks_unread_; }

 private:
  alg::MeshParams params_;
  ReadElsewhere read_elsewhere_;
  bool by_regions_;
  int region_blocks_;
  uint64_t revision_ = 0;
  alg::BlockKeySet elsewhere_before_;
  std::unordered_map<uint64_t, alg::TriangleMesh> regions_;  ///< packed region key -> its mesh
  std::unordered_map<uint64_t, alg::RegionKey> waiting_;
  uint64_t blocks_read_ = 0, blocks_unread_ = 0;
};

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
