// The block store: where a map under a memory budget keeps the blocks it
// moved out of memory (TsdfMap::removeBlocks), compressed with zstd in one
// append-only file, each record with a CRC-32C. Blocks come back
// (TsdfMap::findOrAllocate) when the camera reaches them again. The file is
// scratch space: it is removed when the store goes, and rewritten compactly
// once most of it is blocks already taken back.
//
// Not thread safe: the map's single writer uses it.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>

#include "hxmap/core/expected.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::drv {

struct BlockStoreStats {
  uint64_t blocks = 0;          ///< held now
  uint64_t put = 0, taken = 0;  ///< blocks stored and given back since the start
  uint64_t read_failures = 0;   ///< records that did not read back (I/O error, checksum)
  uint64_t file_bytes = 0;      ///< the store file's size now
  uint64_t live_bytes = 0;      ///< of which records still held
  uint64_t bytes_written = 0;   ///< since the start (compactions included)
  uint64_t compactions = 0;
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

  const std::string& path() const { return path_; }
  BlockStoreStats stats() const;

 private:
  struct Record {
    uint64_t offset = 0;
    uint32_t stored = 0;
    uint32_t crc = 0;
    bool seen_through = false;
  };
  BlockStore(int fd, std::string path);
  void compactIfMostlyDead();

  int fd_ = -1;
  std::string path_;
  std::unordered_map<uint64_t, Record> index_;  ///< packed key -> record
  uint64_t end_ = 0, live_bytes_ = 0;
  BlockStoreStats stats_;
  std::string raw_, packed_;
  void* cctx_ = nullptr;
  void* dctx_ = nullptr;
};

}  // namespace hxmap::drv
