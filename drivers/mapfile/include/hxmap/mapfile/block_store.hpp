// The block store: where a map under a memory budget keeps the blocks it
// moved out of memory (TsdfMap::removeBlocks), compressed with zstd in one
// append-only file, each record with a CRC-32C. Blocks come back
// (TsdfMap::findOrAllocate) when the camera reaches them again. The file is
// scratch space: it is removed when the store goes, and rewritten compactly
// once most of it is blocks already taken back.
//
// DESIGN: put() only copies the block's voxels into a queue (a few
// microseconds); a writer thread of the store's own compresses and writes
// them, so the frontend that moves blocks out does not wait on zstd or the
// disk. A block still queued (or being written) is given back from the
// queue by take(). The queue is bounded (kMaxQueuedBytes): put() waits for
// the writer when the disk cannot keep up, rather than hold memory the
// budget was meant to free. A record the disk refused stays in memory,
// counted, and is still given back: no block is lost to a full disk. The
// same thread reads ahead the blocks the map hints at (prefetch(): the
// camera's predicted view), ahead of its writes, into a bounded cache
// (kMaxReadAheadBytes), so that take() finds them decompressed.
//
// put, take and clear are for one thread (the map's writer); peek, stats
// and flush may be called from any.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "hxmap/core/expected.hpp"
#include "hxmap/mapfile/record_index.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::drv {

struct BlockStoreStats {
  uint64_t blocks = 0;          ///< held now
  uint64_t put = 0, taken = 0;  ///< blocks stored and given back since the start
  uint64_t queued = 0;          ///< of which not yet written (in the writer's queue)
  uint64_t read_failures = 0;   ///< records that did not read back (I/O error, checksum)
  uint64_t write_failures = 0;  ///< records the disk refused (kept in memory instead)
  uint64_t read_ahead = 0;      ///< blocks read ahead of take() (prefetch)
  uint64_t read_ahead_used = 0;  ///< of which take() gave back
  uint64_t file_bytes = 0;      ///< the store file's size now
  uint64_t live_bytes = 0;      ///< of which records still held
  uint64_t bytes_written = 0;   ///< since the start (compactions included)
  uint64_t compactions = 0;
  /// Memory the store holds now: voxels waiting to be written or read
  /// ahead (each bounded below), and the index of the records on disk.
  uint64_t queued_bytes = 0, read_ahead_bytes = 0, index_bytes = 0;
};

class BlockStore : public alg::BlockBacking {
 public:
  /// A store file in `dir` (the system's temporary folder when empty).
  static Expected<std::unique_ptr<BlockStore>> create(const std::string& dir);
  ~BlockStore() override;
  BlockStore(const BlockStore&) = delete;
  BlockStore& operator=(const BlockStore&) = delete;

  bool put(const alg::BlockKey& key, const alg::VoxelBlock& block) override;
  bool take(const alg::BlockKey& key, alg::VoxelBlock& out) override;
  /// Forgets every block (a map rebuilt from scratch no longer needs them).
  void clear() override;
  void prefetch(const std::vector<alg::BlockKey>& keys) override;
  bool ready(const alg::BlockKey& key) const override;
  /// A copy of a block held, which stays held (a checkpoint meshing the
  /// map's blocks out of memory, on its own thread); false when none is
  /// held for `key` or it did not read back. Reads under the store's lock,
  /// as take() does: put and take wait for at most one block's read.
  bool peek(const alg::BlockKey& key, alg::VoxelBlock& out);

  /// Waits until every block put so far is written (or refused) and every
  /// block hinted at is read ahead.
  void flush();

  const std::string& path() const { return path_; }
  BlockStoreStats stats() const;

  /// The writer's queue holds at most this many bytes of voxels.
  static constexpr size_t kMaxQueuedBytes = size_t{32} << 20;
  /// Blocks read ahead and not taken yet hold at most this many bytes (the
  /// oldest are dropped from memory first: their records stay on disk).
  static constexpr size_t kMaxReadAheadBytes = size_t{32} << 20;

 private:
  using Record = RecordIndex::Record;
  /// A block's voxels not (yet) on disk.
  struct Queued {
    std::string raw;
    bool seen_through = false;
  };
  BlockStore(int fd, std::string path);
  void writerLoop();
  /// Writes the in-flight block (writer thread, lock held on entry and exit).
  void writeInFlight(std::unique_lock<std::mutex>& lock);
  void compactIfMostlyDead(std::unique_lock<std::mutex>& lock);
  /// A record's block from the file, through the caller's buffers and
  /// decompression context (take()'s or peek()'s; lock held).
  bool readRecord(const Record& r, alg::VoxelBlock& out, std::string& packed, std::string& raw, void* dctx);
  static void copyOut(const Queued& q, alg::VoxelBlock& out);
  /// Reads the next hinted block into read_ahead_ (writer thread, lock held
  /// on entry and exit).
  void readAhead(std::unique_lock<std::mutex>& lock);

  mutable std::mutex m_;
  std::condition_variable wake_;     ///< the writer: work or stop
  std::condition_variable written_;  ///< put() and flush(): the queue went down
  int fd_ = -1;
  std::string path_;
  RecordIndex index_;                            ///< packed key -> record on disk
  std::unordered_map<uint64_t, Queued> queued_;  ///< packed key -> voxels waiting for the writer
  std::deque<uint64_t> order_;                   ///< queued keys, oldest first (may name keys taken since)
  size_t queued_bytes_ = 0;
  /// The block the writer is compressing and writing: still given back
  /// from here (in_flight_taken_ then tells the writer to drop its record).
  uint64_t in_flight_key_ = 0;
  Queued in_flight_;
  bool writing_ = false, in_flight_taken_ = false;
  bool reading_ = false;  ///< the writer is reading a block ahead
  size_t read_ahead_bytes_ = 0;
  std::unordered_map<uint64_t, Queued> refused_;     ///< the disk refused them: kept here
  std::deque<uint64_t> read_order_;                  ///< hinted keys to read ahead, nearest first
  std::unordered_map<uint64_t, Queued> read_ahead_;  ///< read ahead; the record stays in index_ until taken
  std::deque<uint64_t> read_ahead_age_;              ///< read_ahead_'s keys, oldest first (may name keys gone since)
  uint64_t epoch_ = 0;  ///< clear() counts up: a record written for an earlier epoch is dropped
  uint64_t end_ = 0, live_bytes_ = 0;
  BlockStoreStats stats_;
  std::string raw_, packed_;     ///< take()'s buffers
  std::string writer_packed_;    ///< the writer's
  void* cctx_ = nullptr;         ///< the writer's
  void* dctx_ = nullptr;         ///< take()'s
  void* writer_dctx_ = nullptr;  ///< the writer's, for reading ahead
  std::string peek_packed_, peek_raw_;  ///< peek()'s (under the lock)
  void* peek_dctx_ = nullptr;
  bool stop_ = false;
  std::thread writer_;
};

}  // namespace hxmap::drv
