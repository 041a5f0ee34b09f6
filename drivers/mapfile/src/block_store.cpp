#include "hxmap/mapfile/block_store.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <zstd.h>

#include "hxmap/mapfile/map_file.hpp"

namespace hxmap::drv {

namespace {

constexpr size_t kRaw = sizeof(alg::VoxelBlock::geo) + sizeof(alg::VoxelBlock::color) + sizeof(alg::VoxelBlock::stats);
constexpr uint64_t kCompactAboveBytes = uint64_t{64} << 20;

bool writeAll(int fd, const char* p, size_t n, uint64_t offset) {
  while (n > 0) {
    const ssize_t w = ::pwrite(fd, p, n, static_cast<off_t>(offset));
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    p += w;
    n -= static_cast<size_t>(w);
    offset += static_cast<uint64_t>(w);
  }
  return true;
}

bool readAll(int fd, char* p, size_t n, uint64_t offset) {
  while (n > 0) {
    const ssize_t r = ::pread(fd, p, n, static_cast<off_t>(offset));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return false;
    p += r;
    n -= static_cast<size_t>(r);
    offset += static_cast<uint64_t>(r);
  }
  return true;
}

}  // namespace

Expected<std::unique_ptr<BlockStore>> BlockStore::create(const std::string& dir) {
  static std::atomic<int> serial{0};
  std::error_code ec;
  const std::filesystem::path folder =
      dir.empty() ? std::filesystem::temp_directory_path(ec) : std::filesystem::path(dir);
  const std::string path =
      (folder / fmt::format("hxmap-blocks-{}-{}.tmp", static_cast<long>(::getpid()), serial.fetch_add(1))).string();
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) {
    return Error{
        fmt::format("{}: cannot create the block store (runtime.block_store_dir): {}", path, std::strerror(errno))};
  }
  return std::unique_ptr<BlockStore>(new BlockStore(fd, path));
}

BlockStore::BlockStore(int fd, std::string path)
    : fd_(fd), path_(std::move(path)), cctx_(ZSTD_createCCtx()), dctx_(ZSTD_createDCtx()) {
  raw_.resize(kRaw);
  packed_.resize(ZSTD_compressBound(kRaw));
}

BlockStore::~BlockStore() {
  ZSTD_freeCCtx(static_cast<ZSTD_CCtx*>(cctx_));
  ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(dctx_));
  if (fd_ >= 0) ::close(fd_);
  ::unlink(path_.c_str());
}

bool BlockStore::put(const alg::BlockKey& key, const alg::VoxelBlock& block) {
  std::memcpy(raw_.data(), block.geo, sizeof block.geo);
  std::memcpy(raw_.data() + sizeof block.geo, block.color, sizeof block.color);
  std::memcpy(raw_.data() + sizeof block.geo + sizeof block.color, block.stats, sizeof block.stats);
  const size_t stored =
      ZSTD_compressCCtx(static_cast<ZSTD_CCtx*>(cctx_), packed_.data(), packed_.size(), raw_.data(), kRaw, 1);
  if (ZSTD_isError(stored) || !writeAll(fd_, packed_.data(), stored, end_)) return false;
  const uint64_t k = alg::packBlockKey(key);
  if (const auto old = index_.find(k); old != index_.end()) live_bytes_ -= old->second.stored;  // replaced
  index_[k] = Record{end_, static_cast<uint32_t>(stored), crc32c(packed_.data(), stored), block.seen_through};
  end_ += stored;
  live_bytes_ += stored;
  stats_.bytes_written += stored;
  ++stats_.put;
  return true;
}

bool BlockStore::take(const alg::BlockKey& key, alg::VoxelBlock& out) {
  const auto it = index_.find(alg::packBlockKey(key));
  if (it == index_.end()) return false;
  const Record r = it->second;
  index_.erase(it);
  live_bytes_ -= r.stored;
  bool ok = readAll(fd_, packed_.data(), r.stored, r.offset) && crc32c(packed_.data(), r.stored) == r.crc;
  if (ok) {
    const size_t n = ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(dctx_), raw_.data(), kRaw, packed_.data(), r.stored);
    ok = !ZSTD_isError(n) && n == kRaw;
  }
  if (!ok) {
    ++stats_.read_failures;
    return false;
  }
  std::memcpy(out.geo, raw_.data(), sizeof out.geo);
  std::memcpy(out.color, raw_.data() + sizeof out.geo, sizeof out.color);
  std::memcpy(out.stats, raw_.data() + sizeof out.geo + sizeof out.color, sizeof out.stats);
  out.seen_through = r.seen_through;
  ++stats_.taken;
  compactIfMostlyDead();
  return true;
}

void BlockStore::clear() {
  index_.clear();
  live_bytes_ = 0;
  end_ = 0;
  if (::ftruncate(fd_, 0) != 0) {
    // The old bytes stay allocated on disk; records are written from 0 again either way.
  }
}

void BlockStore::compactIfMostlyDead() {
  // DESIGN: records of blocks taken back are dead bytes; a long run that
  // moves back and forth would grow the file without bound. Once it is
  // past kCompactAboveBytes and less than a third of it is live, the live
  // records are copied into a fresh file (a one-off cost of reading and
  // writing the live third).
  if (end_ < kCompactAboveBytes || live_bytes_ * 3 > end_) return;
  const std::string tmp = path_ + ".compact";
  const int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) return;
  uint64_t end = 0;
  std::string buf;
  std::vector<std::pair<Record*, uint64_t>> moved;  // applied once the new file is in place
  moved.reserve(index_.size());
  for (auto& [k, r] : index_) {
    buf.resize(r.stored);
    if (!readAll(fd_, buf.data(), r.stored, r.offset) || !writeAll(fd, buf.data(), r.stored, end)) {
      ::close(fd);
      ::unlink(tmp.c_str());
      return;
    }
    moved.emplace_back(&r, end);
    end += r.stored;
  }
  if (::rename(tmp.c_str(), path_.c_str()) != 0) {
    ::close(fd);
    ::unlink(tmp.c_str());
    return;
  }
  for (auto& [r, offset] : moved) r->offset = offset;
  ::close(fd_);
  fd_ = fd;
  stats_.bytes_written += end;
  end_ = end;
  ++stats_.compactions;
}

BlockStoreStats BlockStore::stats() const {
  BlockStoreStats s = stats_;
  s.blocks = index_.size();
  s.file_bytes = end_;
  s.live_bytes = live_bytes_;
  return s;
}

}  // namespace hxmap::drv
