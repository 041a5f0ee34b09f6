#include "hxmap/mapfile/block_store.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <zstd.h>

#include "hxmap/mapfile/map_file.hpp"
#include "voxel_bytes.hpp"

namespace hxmap::drv {

namespace {

constexpr uint64_t kCompactAboveBytes = uint64_t{64} << 20;

/// All of n bytes through pread or pwrite at `offset` (short transfers and
/// EINTR retried); false on an error or end of file.
template <typename Transfer, typename Byte>
bool transferAll(Transfer transfer, int fd, Byte* p, size_t n, uint64_t offset) {
  while (n > 0) {
    const ssize_t done = transfer(fd, p, n, static_cast<off_t>(offset));
    if (done < 0 && errno == EINTR) continue;
    if (done <= 0) return false;
    p += done;
    n -= static_cast<size_t>(done);
    offset += static_cast<uint64_t>(done);
  }
  return true;
}
bool writeAll(int fd, const char* p, size_t n, uint64_t offset) { return transferAll(::pwrite, fd, p, n, offset); }
bool readAll(int fd, char* p, size_t n, uint64_t offset) { return transferAll(::pread, fd, p, n, offset); }

/// A record's kBlockRawBytes of voxels into `raw`, through `packed`; false
/// on a short read, a checksum that does not match or a bad frame.
bool readRaw(int fd, uint64_t offset, uint32_t stored, uint32_t crc, std::string& packed, std::string& raw,
             void* dctx) {
  packed.resize(std::max<size_t>(packed.size(), stored));
  raw.resize(kBlockRawBytes);
  if (!readAll(fd, packed.data(), stored, offset) || crc32c(packed.data(), stored) != crc) return false;
  const size_t n =
      ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(dctx), raw.data(), kBlockRawBytes, packed.data(), stored);
  return !ZSTD_isError(n) && n == kBlockRawBytes;
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
    : fd_(fd),
      path_(std::move(path)),
      cctx_(ZSTD_createCCtx()),
      dctx_(ZSTD_createDCtx()),
      writer_dctx_(ZSTD_createDCtx()),
      peek_dctx_(ZSTD_createDCtx()) {
  raw_.resize(kBlockRawBytes);
  packed_.resize(ZSTD_compressBound(kBlockRawBytes));
  writer_packed_.resize(ZSTD_compressBound(kBlockRawBytes));
  writer_ = std::thread([this] { writerLoop(); });
}

BlockStore::~BlockStore() {
  {
    std::lock_guard lock(m_);
    stop_ = true;
  }
  wake_.notify_all();
  writer_.join();
  ZSTD_freeCCtx(static_cast<ZSTD_CCtx*>(cctx_));
  ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(dctx_));
  ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(writer_dctx_));
  ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(peek_dctx_));
  if (fd_ >= 0) ::close(fd_);
  ::unlink(path_.c_str());
}

bool BlockStore::put(const alg::BlockKey& key, const alg::VoxelBlock& block) {
  Queued q;
  packBlock(block, q.raw);
  q.seen_through = block.seen_through;
  const uint64_t k = alg::packBlockKey(key);
  {
    std::unique_lock lock(m_);
    written_.wait(lock, [&] { return queued_bytes_ < kMaxQueuedBytes; });
    // A key put again replaces what the store held for it.
    if (const auto old = index_.find(k)) {
      live_bytes_ -= old->stored;
      index_.erase(k);
    }
    if (queued_.erase(k) > 0) queued_bytes_ -= kBlockRawBytes;
    refused_.erase(k);
    if (read_ahead_.erase(k) > 0) read_ahead_bytes_ -= kBlockRawBytes;
    if (writing_ && in_flight_key_ == k) in_flight_taken_ = true;
    queued_.emplace(k, std::move(q));
    queued_bytes_ += kBlockRawBytes;
    order_.push_back(k);
    ++stats_.put;
  }
  wake_.notify_one();
  return true;
}

bool BlockStore::take(const alg::BlockKey& key, alg::VoxelBlock& out) {
  const uint64_t k = alg::packBlockKey(key);
  std::unique_lock lock(m_);
  auto giveBack = [&](const Queued& q) {
    copyOut(q, out);
    ++stats_.taken;
    return true;
  };
  if (const auto it = queued_.find(k); it != queued_.end()) {
    giveBack(it->second);
    queued_.erase(it);
    queued_bytes_ -= kBlockRawBytes;
    lock.unlock();
    written_.notify_all();
    return true;
  }
  if (writing_ && !in_flight_taken_ && in_flight_key_ == k) {
    // The writer reads the same bytes meanwhile; it drops its record.
    in_flight_taken_ = true;
    return giveBack(in_flight_);
  }
  if (const auto it = refused_.find(k); it != refused_.end()) {
    giveBack(it->second);
    refused_.erase(it);
    return true;
  }
  const auto found = index_.find(k);
  if (!found) return false;
  const Record r = *found;
  index_.erase(k);
  live_bytes_ -= r.stored;
  if (const auto ahead = read_ahead_.find(k); ahead != read_ahead_.end()) {
    giveBack(ahead->second);
    read_ahead_.erase(ahead);
    read_ahead_bytes_ -= kBlockRawBytes;
    ++stats_.read_ahead_used;
    return true;
  }
  if (!readRecord(r, out, packed_, raw_, dctx_)) {
    ++stats_.read_failures;
    return false;
  }
  ++stats_.taken;
  return true;
}

bool BlockStore::peek(const alg::BlockKey& key, alg::VoxelBlock& out) {
  const uint64_t k = alg::packBlockKey(key);
  std::lock_guard lock(m_);
  const Queued* held = nullptr;  // voxels in memory: queued, being written, refused or read ahead
  if (const auto it = queued_.find(k); it != queued_.end()) {
    held = &it->second;
  } else if (writing_ && !in_flight_taken_ && in_flight_key_ == k) {
    held = &in_flight_;
  } else if (const auto refused = refused_.find(k); refused != refused_.end()) {
    held = &refused->second;
  } else if (const auto ahead = read_ahead_.find(k); ahead != read_ahead_.end()) {
    held = &ahead->second;
  }
  if (held != nullptr) {
    copyOut(*held, out);
    return true;
  }
  const auto found = index_.find(k);
  return found && readRecord(*found, out, peek_packed_, peek_raw_, peek_dctx_);
}

void BlockStore::copyOut(const Queued& q, alg::VoxelBlock& out) {
  unpackBlock(q.raw.data(), out);
  out.seen_through = q.seen_through;
}

bool BlockStore::readRecord(const Record& r, alg::VoxelBlock& out, std::string& packed, std::string& raw, void* dctx) {
  if (!readRaw(fd_, r.offset, r.stored, r.crc, packed, raw, dctx)) return false;
  unpackBlock(raw.data(), out);
  out.seen_through = r.seen_through;
  return true;
}

void BlockStore::clear() {
  {
    std::lock_guard lock(m_);
    index_.clear();
    queued_.clear();
    order_.clear();
    refused_.clear();
    read_order_.clear();
    read_ahead_.clear();
    read_ahead_age_.clear();
    read_ahead_bytes_ = 0;
    queued_bytes_ = 0;
    in_flight_taken_ = true;  // a block being written is dropped with the rest
    ++epoch_;
    live_bytes_ = 0;
    end_ = 0;
    if (::ftruncate(fd_, 0) != 0) {
      // The old bytes stay allocated on disk; records are written from 0 again either way.
    }
  }
  written_.notify_all();
}

void BlockStore::flush() {
  std::unique_lock lock(m_);
  written_.wait(lock, [&] { return order_.empty() && !writing_ && read_order_.empty() && !reading_; });
}

void BlockStore::prefetch(const std::vector<alg::BlockKey>& keys) {
  {
    std::lock_guard lock(m_);
    read_order_.clear();  // the previous hint's view is behind the camera now
    for (const alg::BlockKey& key : keys) {
      const uint64_t k = alg::packBlockKey(key);
      if (index_.contains(k) && read_ahead_.count(k) == 0) read_order_.push_back(k);
    }
    if (read_order_.empty()) return;
  }
  wake_.notify_one();
}

bool BlockStore::ready(const alg::BlockKey& key) const {
  const uint64_t k = alg::packBlockKey(key);
  std::lock_guard lock(m_);
  return !index_.contains(k) || read_ahead_.count(k) > 0;
}

void BlockStore::readAhead(std::unique_lock<std::mutex>& lock) {
  const uint64_t k = read_order_.front();
  read_order_.pop_front();
  const auto found = index_.find(k);
  if (!found || read_ahead_.count(k) > 0) return;
  const Record r = *found;
  const int fd = fd_;  // only this thread replaces it (compaction)
  const uint64_t epoch = epoch_;
  reading_ = true;
  lock.unlock();
  Queued q;
  const bool ok = readRaw(fd, r.offset, r.stored, r.crc, writer_packed_, q.raw, writer_dctx_);
  q.seen_through = r.seen_through;
  lock.lock();
  reading_ = false;
  const auto now = index_.find(k);
  if (!ok || epoch != epoch_ || !now || now->offset != r.offset) return;  // taken meanwhile
  read_ahead_.emplace(k, std::move(q));
  read_ahead_bytes_ += kBlockRawBytes;
  read_ahead_age_.push_back(k);
  ++stats_.read_ahead;
  while (read_ahead_bytes_ > kMaxReadAheadBytes && !read_ahead_age_.empty()) {
    if (read_ahead_.erase(read_ahead_age_.front()) > 0) read_ahead_bytes_ -= kBlockRawBytes;
    read_ahead_age_.pop_front();
  }
  if (read_ahead_age_.size() > 2 * read_ahead_.size() + 1024) {  // keys taken since: drop them from the age list
    std::deque<uint64_t> age;
    for (const uint64_t a : read_ahead_age_) {
      if (read_ahead_.count(a) > 0) age.push_back(a);
    }
    read_ahead_age_.swap(age);
  }
}

void BlockStore::writerLoop() {
  std::unique_lock lock(m_);
  for (;;) {
    wake_.wait(lock, [&] { return stop_ || !order_.empty() || !read_order_.empty(); });
    if (stop_) return;
    if (!read_order_.empty()) {  // reads first: the map is about to want them
      readAhead(lock);
      lock.unlock();
      written_.notify_all();
      lock.lock();
      continue;
    }
    const uint64_t k = order_.front();
    order_.pop_front();
    if (const auto it = queued_.find(k); it != queued_.end()) {  // else taken back before its turn
      in_flight_key_ = k;
      in_flight_ = std::move(it->second);
      queued_.erase(it);
      queued_bytes_ -= kBlockRawBytes;
      writing_ = true;
      in_flight_taken_ = false;
      writeInFlight(lock);
      writing_ = false;
    }
    lock.unlock();
    written_.notify_all();
    lock.lock();
  }
}

void BlockStore::writeInFlight(std::unique_lock<std::mutex>& lock) {
  // Compressed and written without the lock: take() may give the block
  // back meanwhile (from in_flight_, which nobody writes until this
  // returns), and clear() may drop it (epoch_).
  const uint64_t epoch = epoch_;
  lock.unlock();
  const size_t stored = ZSTD_compressCCtx(static_cast<ZSTD_CCtx*>(cctx_), writer_packed_.data(), writer_packed_.size(),
                                          in_flight_.raw.data(), kBlockRawBytes, 1);
  const bool packed = !ZSTD_isError(stored);
  const uint32_t crc = packed ? crc32c(writer_packed_.data(), stored) : 0;
  lock.lock();
  if (in_flight_taken_ || epoch != epoch_) return;
  // Only this thread appends, so the offset it takes is its own.
  const uint64_t offset = end_;
  const int fd = fd_;
  if (packed) end_ += stored;
  lock.unlock();
  const bool ok = packed && writeAll(fd, writer_packed_.data(), stored, offset);
  lock.lock();
  if (epoch != epoch_) return;
  if (!ok && packed && end_ == offset + stored) end_ = offset;
  if (in_flight_taken_) return;  // its bytes are dead
  if (!ok) {
    ++stats_.write_failures;
    refused_[in_flight_key_] = std::move(in_flight_);
    return;
  }
  index_.set(in_flight_key_, Record{offset, static_cast<uint32_t>(stored), crc, in_flight_.seen_through});
  live_bytes_ += stored;
  stats_.bytes_written += stored;
  compactIfMostlyDead(lock);
}

void BlockStore::compactIfMostlyDead(std::unique_lock<std::mutex>& lock) {
  // DESIGN: records of blocks taken back are dead bytes; a long run that
  // moves back and forth would grow the file without bound. Once it is
  // past kCompactAboveBytes and less than a third of it is live, the live
  // records are copied into a fresh file (a one-off cost of reading and
  // writing the live third, on the writer thread: take() reads the old
  // file meanwhile, and only this thread writes).
  if (end_ < kCompactAboveBytes || live_bytes_ * 3 > end_) return;
  std::vector<std::pair<uint64_t, Record>> live;
  live.reserve(index_.size());
  index_.forEach([&](uint64_t k, const Record& r) { live.emplace_back(k, r); });
  const int old_fd = fd_;
  const uint64_t epoch = epoch_;
  lock.unlock();
  const std::string tmp = path_ + ".compact";
  const int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  uint64_t end = 0;
  std::vector<uint64_t> offsets;
  offsets.reserve(live.size());
  bool ok = fd >= 0;
  std::string buf;
  for (size_t i = 0; ok && i < live.size(); ++i) {
    const Record& r = live[i].second;
    buf.resize(r.stored);
    ok = readAll(old_fd, buf.data(), r.stored, r.offset) && writeAll(fd, buf.data(), r.stored, end);
    offsets.push_back(end);
    end += r.stored;
  }
  lock.lock();
  ok = ok && epoch == epoch_ && ::rename(tmp.c_str(), path_.c_str()) == 0;
  if (!ok) {
    if (fd >= 0) ::close(fd);
    ::unlink(tmp.c_str());
    return;
  }
  // Records taken back meanwhile are gone from the index; their copies
  // are dead bytes in the new file.
  for (size_t i = 0; i < live.size(); ++i) index_.moveIfAt(live[i].first, live[i].second.offset, offsets[i]);
  ::close(fd_);
  fd_ = fd;
  stats_.bytes_written += end;
  end_ = end;
  ++stats_.compactions;
}

BlockStoreStats BlockStore::stats() const {
  std::lock_guard lock(m_);
  BlockStoreStats s = stats_;
  const uint64_t in_flight = writing_ && !in_flight_taken_ ? 1 : 0;
  s.queued = queued_.size() + in_flight;
  s.blocks = index_.size() + refused_.size() + s.queued;
  s.file_bytes = end_;
  s.live_bytes = live_bytes_;
  s.queued_bytes = queued_bytes_ + in_flight * kBlockRawBytes;
  s.read_ahead_bytes = read_ahead_bytes_;
  s.index_bytes = index_.memoryBytes();
  return s;
}

}  // namespace hxmap::drv
