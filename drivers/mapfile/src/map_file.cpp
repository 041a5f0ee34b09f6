#include "hxmap/mapfile/map_file.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <type_traits>

#include <fmt/format.h>
#include <zstd.h>

#include "voxel_bytes.hpp"

namespace hxmap::drv {

namespace {

namespace fs = std::filesystem;

constexpr char kMagic[8] = {'H', 'X', 'M', 'A', 'P', 'T', 'S', 'D'};
constexpr char kEndMagic[8] = {'H', 'X', 'M', 'A', 'P', 'E', 'N', 'D'};
constexpr uint32_t kBlockTag = 0x314b4c42;     // "BLK1"
constexpr uint32_t kKeyframeTag = 0x3152464b;  // "KFR1"
constexpr size_t kFramesField = 64;
constexpr int kZstdLevel = 1;  // fast; level 3 saved 6 % more on the fr1/xyz map at twice the time

// The fixed layout of the header (version 1), in file order.
constexpr size_t kHeaderBytes = 8 + 4 + 4 + 3 * 8 + 4 + 4 + 8 + 8 + kFramesField + 4;
constexpr size_t kTrailerBytes = 8 + 8 + 8 + 4;
// Block record: tag, key (3 x i32), flags (u32), stored size, CRC.
constexpr size_t kBlockRecordHead = 4 + 12 + 4 + 4 + 4;
// Keyframe record: tag, id, pose (12 x f64), count, descriptor width, CRC.
constexpr size_t kKeyframeRecordHead = 4 + 4 + 12 * 8 + 4 + 4 + 4;

std::array<uint32_t, 256> makeCrcTable() {
  std::array<uint32_t, 256> t{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ 0x82f63b78u : c >> 1;
    t[i] = c;
  }
  return t;
}

/// Appends little-endian values to a byte buffer (the host is little-endian:
/// checked at configure time by the toolchains hxmap builds with).
class Bytes {
 public:
  template <typename T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    append(&v, sizeof v);
  }
  void append(const void* p, size_t n) {
    const auto* c = static_cast<const char*>(p);
    data_.insert(data_.end(), c, c + n);
  }
  const std::string& data() const { return data_; }
  void clear() { data_.clear(); }
  void patch(size_t at, uint32_t v) { std::memcpy(data_.data() + at, &v, sizeof v); }

 private:
  std::string data_;
};

/// Reads little-endian values from a byte range, tracking the offset.
class Cursor {
 public:
  Cursor(const char* begin, size_t size, size_t offset = 0) : p_(begin), size_(size), offset_(offset) {}
  size_t offset() const { return offset_; }
  size_t left() const { return size_ - offset_; }
  void seek(size_t offset) { offset_ = offset; }
  template <typename T>
  bool get(T& v) {
    if (left() < sizeof v) return false;
    std::memcpy(&v, p_ + offset_, sizeof v);
    offset_ += sizeof v;
    return true;
  }
  const char* here() const { return p_ + offset_; }
  bool skip(size_t n) {
    if (left() < n) return false;
    offset_ += n;
    return true;
  }

 private:
  const char* p_;
  size_t size_, offset_;
};

std::string errnoText() { return std::strerror(errno); }

void putHeader(Bytes& b, const alg::TsdfParams& p, uint64_t blocks, uint64_t keyframes) {
  b.append(kMagic, sizeof kMagic);
  b.put(kMapFileVersion);
  b.put(static_cast<uint32_t>(kHeaderBytes));
  b.put(p.voxel_size_m);
  b.put(p.truncation_m);
  b.put(p.max_weight);
  b.put(static_cast<uint32_t>(alg::kBlockSide));
  b.put(static_cast<uint32_t>(kVoxelRecordBytes));
  b.put(blocks);
  b.put(keyframes);
  char frames[kFramesField] = {};
  std::strncpy(frames, kMapFileFrames, kFramesField - 1);
  b.append(frames, kFramesField);
  b.put(crc32c(b.data().data(), b.data().size()));
}

/// The header, parsed and checked; the cursor is left after it.
Expected<MapFileInfo> parseHeader(const std::string& path, Cursor& c) {
  char magic[8];
  if (!c.get(magic) || std::memcmp(magic, kMagic, sizeof magic) != 0) {
    return Error{path + ": not an hxmap map file (no HXMAPTSD header at offset 0)"};
  }
  MapFileInfo info;
  uint32_t header_bytes = 0;
  if (!c.get(info.version)) return Error{path + ": truncated in its header (offset 8)"};
  if (info.version != kMapFileVersion) {
    return Error{fmt::format("{}: map file format version {}, this build reads version {}", path, info.version,
                             kMapFileVersion)};
  }
  if (!c.get(header_bytes) || header_bytes != kHeaderBytes) {
    return Error{fmt::format("{}: header size {} at offset 12, version {} has {}", path, header_bytes, kMapFileVersion,
                             kHeaderBytes)};
  }
  if (c.left() + c.offset() < kHeaderBytes) return Error{path + ": truncated in its header"};
  uint32_t block_side = 0, voxel_bytes = 0, crc = 0;
  char frames[kFramesField];
  c.get(info.tsdf.voxel_size_m);
  c.get(info.tsdf.truncation_m);
  c.get(info.tsdf.max_weight);
  c.get(block_side);
  c.get(voxel_bytes);
  c.get(info.blocks);
  c.get(info.keyframes);
  c.get(frames);
  const size_t crc_offset = c.offset();
  c.get(crc);
  if (crc != crc32c(c.here() - kHeaderBytes, kHeaderBytes - 4)) {
    return Error{fmt::format("{}: header checksum mismatch (offset {}): the file is corrupt", path, crc_offset)};
  }
  if (block_side != static_cast<uint32_t>(alg::kBlockSide) || voxel_bytes != kVoxelRecordBytes) {
    return Error{fmt::format("{}: blocks of {}^3 voxels of {} bytes, this build uses {}^3 of {}", path, block_side,
                             voxel_bytes, alg::kBlockSide, kVoxelRecordBytes)};
  }
  // The ranges the configuration accepts (config.cpp), so that a map file
  // never makes a map the configuration could not.
  const alg::TsdfParams& t = info.tsdf;
  if (!(t.voxel_size_m >= 0.002 && t.voxel_size_m <= 0.5) || !(t.truncation_m >= 0.004 && t.truncation_m <= 2) ||
      !(t.max_weight >= 1 && t.max_weight <= 1e4)) {
    return Error{fmt::format("{}: header holds voxel size {} m, truncation {} m, weight cap {}: out of range", path,
                             t.voxel_size_m, t.truncation_m, t.max_weight)};
  }
  frames[kFramesField - 1] = 0;
  info.frames = frames;
  return info;
}

/// The trailer at the file's end; an error when the file was cut short.
Status checkTrailer(const std::string& path, const char* data, size_t size, const MapFileInfo& info) {
  if (size < kHeaderBytes + kTrailerBytes) {
    return Error{fmt::format("{}: truncated: {} bytes, no end marker (was the writer killed?)", path, size)};
  }
  Cursor c(data, size, size - kTrailerBytes);
  char magic[8];
  uint64_t blocks = 0, keyframes = 0;
  uint32_t crc = 0;
  c.get(magic);
  c.get(blocks);
  c.get(keyframes);
  c.get(crc);
  if (std::memcmp(magic, kEndMagic, sizeof magic) != 0 || crc != crc32c(data + size - kTrailerBytes, 24)) {
    return Error{fmt::format("{}: truncated or corrupt: no end marker at offset {} (was the writer killed?)", path,
                             size - kTrailerBytes)};
  }
  if (blocks != info.blocks || keyframes != info.keyframes) {
    return Error{fmt::format("{}: the header counts {} blocks and {} keyframes, the end marker {} and {}", path,
                             info.blocks, info.keyframes, blocks, keyframes)};
  }
  return Status::ok();
}

Expected<std::string> readWholeFile(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return Error{path + ": cannot open: " + errnoText()};
  std::string data;
  char buf[1 << 16];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f.get())) > 0) data.append(buf, n);
  if (std::ferror(f.get())) return Error{path + ": read error: " + errnoText()};
  return data;
}

/// Writes to a temporary file beside the target and renames it over the
/// target once all of it is on disk.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path)
      : path_(std::move(path)), tmp_(fmt::format("{}.tmp.{}", path_, static_cast<long>(::getpid()))) {}
  ~AtomicFile() {
    if (f_) std::fclose(f_);
    if (!committed_) {
      std::error_code ignored;
      fs::remove(tmp_, ignored);
    }
  }
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  Status open() {
    f_ = std::fopen(tmp_.c_str(), "wb");
    if (!f_) return Error{tmp_ + ": cannot create (does the folder exist and is it writable?): " + errnoText()};
    return Status::ok();
  }
  bool write(const std::string& bytes) {
    if (std::fwrite(bytes.data(), 1, bytes.size(), f_) != bytes.size()) return false;
    written_ += bytes.size();
    return true;
  }
  uint64_t written() const { return written_; }
  Status commit() {
    if (std::fflush(f_) != 0 || ::fsync(::fileno(f_)) != 0) return Error{tmp_ + ": write failed: " + errnoText()};
    const int rc = std::fclose(f_);
    f_ = nullptr;
    if (rc != 0) return Error{tmp_ + ": write failed: " + errnoText()};
    std::error_code ec;
    fs::rename(tmp_, path_, ec);
    if (ec) return Error{path_ + ": cannot rename the temporary file over it: " + ec.message()};
    committed_ = true;
    // The rename itself reaches the disk with the folder's entry.
    const fs::path dir = fs::absolute(fs::path(path_)).parent_path();
    const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd >= 0) {
      (void)::fsync(fd);  // best effort: some file systems refuse fsync on folders
      ::close(fd);
    }
    return Status::ok();
  }
  std::string failure() const { return path_ + ": write failed (disk full?): " + errnoText(); }

 private:
  std::string path_, tmp_;
  FILE* f_ = nullptr;
  uint64_t written_ = 0;
  bool committed_ = false;
};

void putKeyframe(Bytes& b, const alg::KeyframeDatabase::Keyframe& k) {
  const cv::Mat d = k.descriptors.isContinuous() ? k.descriptors : k.descriptors.clone();
  const uint32_t n = static_cast<uint32_t>(std::min<size_t>(static_cast<size_t>(d.rows), k.points_cam.size()));
  const uint32_t width = static_cast<uint32_t>(d.cols);
  b.put(kKeyframeTag);
  b.put(k.id);
  const Eigen::Matrix3d R = k.T_world_cam.linear();
  for (int r = 0; r < 3; ++r) {
    for (int col = 0; col < 3; ++col) b.put(R(r, col));
  }
  for (int r = 0; r < 3; ++r) b.put(k.T_world_cam.translation()[r]);
  b.put(n);
  b.put(width);
  const size_t crc_at = b.data().size();
  b.put(uint32_t{0});  // the CRC, once the payload is in
  b.append(d.data, static_cast<size_t>(n) * width);
  for (uint32_t i = 0; i < n; ++i) b.append(k.points_cam[i].data(), 3 * sizeof(float));
  const std::string& s = b.data();
  uint32_t crc = crc32c(s.data() + crc_at - (kKeyframeRecordHead - 4), kKeyframeRecordHead - 4);
  crc = crc32c(s.data() + crc_at + 4, s.size() - crc_at - 4, crc);
  b.patch(crc_at, crc);
}

}  // namespace

uint32_t crc32c(const void* data, size_t n, uint32_t crc) {
  static const std::array<uint32_t, 256> table = makeCrcTable();
  const auto* p = static_cast<const uint8_t*>(data);
  crc = ~crc;
  for (size_t i = 0; i < n; ++i) crc = table[(crc ^ p[i]) & 0xff] ^ (crc >> 8);
  return ~crc;
}

Expected<MapSaveStats> saveMap(const std::string& path, const alg::TsdfMap& map,
                               const alg::KeyframeDatabase* keyframes) {
  AtomicFile file(path);
  if (Status s = file.open(); !s) return Error{s.message()};
  const uint64_t n_keyframes = keyframes ? keyframes->size() : 0;
  Bytes b;
  putHeader(b, map.params(), map.blockCount(), n_keyframes);
  if (!file.write(b.data())) return Error{file.failure()};

  std::string raw, packed(ZSTD_compressBound(kBlockRawBytes), '\0');
  std::unique_ptr<ZSTD_CCtx, size_t (*)(ZSTD_CCtx*)> cctx(ZSTD_createCCtx(), &ZSTD_freeCCtx);
  for (size_t i = 0; i < map.blockCount(); ++i) {
    const alg::VoxelBlock& block = map.block(i);
    packBlock(block, raw);
    const size_t stored =
        ZSTD_compressCCtx(cctx.get(), packed.data(), packed.size(), raw.data(), raw.size(), kZstdLevel);
    if (ZSTD_isError(stored)) return Error{path + ": compressing a block failed: " + ZSTD_getErrorName(stored)};
    b.clear();
    b.put(kBlockTag);
    const alg::BlockKey& key = map.key(i);
    b.put(static_cast<int32_t>(key.x()));
    b.put(static_cast<int32_t>(key.y()));
    b.put(static_cast<int32_t>(key.z()));
    b.put(static_cast<uint32_t>(block.seen_through ? 1 : 0));
    b.put(static_cast<uint32_t>(stored));
    uint32_t crc = crc32c(b.data().data(), b.data().size());
    crc = crc32c(packed.data(), stored, crc);
    b.put(crc);
    b.append(packed.data(), stored);
    if (!file.write(b.data())) return Error{file.failure()};
  }
  if (keyframes) {
    for (const auto& k : keyframes->keyframes()) {
      b.clear();
      putKeyframe(b, k);
      if (!file.write(b.data())) return Error{file.failure()};
    }
  }
  b.clear();
  b.append(kEndMagic, sizeof kEndMagic);
  b.put(static_cast<uint64_t>(map.blockCount()));
  b.put(n_keyframes);
  b.put(crc32c(b.data().data(), b.data().size()));
  if (!file.write(b.data())) return Error{file.failure()};
  const uint64_t bytes = file.written();
  if (Status s = file.commit(); !s) return Error{s.message()};
  return MapSaveStats{map.blockCount(), n_keyframes, bytes};
}

namespace {

/// Reads the records after the header into `out`.
class RecordReader {
 public:
  RecordReader(const std::string& path, Cursor& c, size_t records_end, const MapLoadOptions& options, LoadedMap& out)
      : path_(path), c_(c), end_(records_end), options_(options), out_(out) {}

  Status readBlocks() {
    std::unique_ptr<ZSTD_DCtx, size_t (*)(ZSTD_DCtx*)> dctx(ZSTD_createDCtx(), &ZSTD_freeDCtx);
    std::string raw(kBlockRawBytes, '\0');
    const size_t max_stored = ZSTD_compressBound(kBlockRawBytes);
    for (uint64_t i = 0; i < out_.info.blocks; ++i) {
      const size_t at = c_.offset();
      uint32_t tag = 0, flags = 0, stored = 0, crc = 0;
      int32_t key[3] = {0, 0, 0};
      if (end_ - at < kBlockRecordHead) return truncated("block", i, at);
      c_.get(tag);
      c_.get(key);
      c_.get(flags);
      c_.get(stored);
      c_.get(crc);
      if (tag != kBlockTag || stored > max_stored || stored > end_ - c_.offset()) {
        bool done = false;
        const std::string what = fmt::format("block {} of {}: no block record at offset {}", i + 1, out_.info.blocks, at);
        if (Status s = skipBadHead(what, at, kBlockTag, out_.skipped_blocks, done); !s || done) return s;
        continue;
      }
      const char* payload = c_.here();
      const uint32_t check = recordCrc(kBlockRecordHead, stored);
      out_.info.block_bytes += stored;
      const size_t got = check == crc ? ZSTD_decompressDCtx(dctx.get(), raw.data(), raw.size(), payload, stored) : 0;
      if (check != crc || ZSTD_isError(got) || got != kBlockRawBytes) {
        if (Status s = bad(fmt::format("block {} of {} at offset {} ({}, {}, {}): checksum mismatch", i + 1,
                                       out_.info.blocks, at, key[0], key[1], key[2]));
            !s) {
          return s;
        }
        ++out_.skipped_blocks;
        continue;
      }
      const alg::BlockKey k(key[0], key[1], key[2]);
      // Keys pack into 21 bits per axis (packBlockKey): a key beyond is not
      // one a map could hold.
      const auto outside = [](int32_t v) { return v < -(1 << 20) || v >= (1 << 20); };
      if (outside(key[0]) || outside(key[1]) || outside(key[2]) || out_.map.find(k) >= 0) {
        if (Status s = bad(fmt::format("block {} at offset {}: key ({}, {}, {}) out of range or a second time", i + 1,
                                       at, key[0], key[1], key[2]));
            !s) {
          return s;
        }
        ++out_.skipped_blocks;
        continue;
      }
      alg::VoxelBlock& b = out_.map.block(static_cast<size_t>(out_.map.findOrAllocate(k)));
      unpackBlock(raw.data(), b);
      b.seen_through = (flags & 1u) != 0;
    }
    return Status::ok();
  }

  Status readKeyframes() {
    for (uint64_t i = 0; i < out_.info.keyframes; ++i) {
      const size_t at = c_.offset();
      if (end_ - at < kKeyframeRecordHead) return truncated("keyframe", i, at);
      uint32_t tag = 0, id = 0, n = 0, width = 0, crc = 0;
      double pose[12];
      c_.get(tag);
      c_.get(id);
      c_.get(pose);
      c_.get(n);
      c_.get(width);
      c_.get(crc);
      const uint64_t payload = static_cast<uint64_t>(n) * (width + 3 * sizeof(float));
      if (tag != kKeyframeTag || width > 256 || payload > end_ - c_.offset()) {
        bool done = false;
        const std::string what =
            fmt::format("keyframe {} of {}: no keyframe record at offset {}", i + 1, out_.info.keyframes, at);
        if (Status s = skipBadHead(what, at, kKeyframeTag, out_.skipped_keyframes, done); !s || done) return s;
        continue;
      }
      const char* p = c_.here();
      const uint32_t check = recordCrc(kKeyframeRecordHead, payload);
      Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
      for (int r = 0; r < 3; ++r) {
        for (int col = 0; col < 3; ++col) T.linear()(r, col) = pose[3 * r + col];
        T.translation()[r] = pose[9 + r];
      }
      bool sane = T.matrix().allFinite() &&
                  (T.linear().transpose() * T.linear() - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
                  (n == 0 || width == 32);  // ORB descriptors
      for (uint32_t j = 0; sane && j < n; ++j) {
        float q[3];
        std::memcpy(q, p + static_cast<size_t>(n) * width + j * 3 * sizeof(float), sizeof q);
        sane = std::isfinite(q[0]) && std::isfinite(q[1]) && std::isfinite(q[2]);
      }
      if (check != crc || !sane) {
        if (Status s = bad(fmt::format("keyframe {} of {} (id {}) at offset {}: checksum mismatch or not a keyframe",
                                       i + 1, out_.info.keyframes, id, at));
            !s) {
          return s;
        }
        ++out_.skipped_keyframes;
        continue;
      }
      alg::FrameFeatures f;
      f.descriptors = cv::Mat(static_cast<int>(n), static_cast<int>(width), CV_8U);
      if (n > 0 && width > 0) std::memcpy(f.descriptors.data, p, static_cast<size_t>(n) * width);
      f.points_cam.resize(n);
      for (uint32_t j = 0; j < n; ++j) {
        std::memcpy(f.points_cam[j].data(), p + static_cast<size_t>(n) * width + j * 3 * sizeof(float),
                    3 * sizeof(float));
      }
      f.pixels.resize(n);  // not kept by the database
      out_.keyframes.add(id, f, T);
    }
    return Status::ok();
  }

 private:
  Status truncated(const char* what, uint64_t i, size_t at) const {
    return Error{fmt::format("{}: truncated at offset {}: {} {} of {} is cut short", path_, at, what, i + 1,
                             what[0] == 'b' ? out_.info.blocks : out_.info.keyframes)};
  }
  /// A corrupt record: an error naming it, or (skip_bad) a logged skip.
  Status bad(const std::string& what) const {
    if (!options_.skip_bad) return Error{path_ + ": " + what + " (--skip-bad leaves corrupt records out)"};
    return Status::ok();
  }
  /// The CRC-32C of the record whose head (`head` bytes, its own CRC last)
  /// ends at the cursor and of the `payload` bytes after, which the cursor
  /// then steps over.
  uint32_t recordCrc(size_t head, uint64_t payload) {
    const char* p = c_.here();
    const uint32_t crc = crc32c(p, payload, crc32c(p - head, head - 4));
    c_.skip(payload);
    return crc;
  }
  /// A record head that is not one (`what`, at `at`): an error, or with
  /// skip_bad on to the next record tagged `tag` (`done` when none is left:
  /// the rest were lost), counted in `skipped`.
  Status skipBadHead(const std::string& what, size_t at, uint32_t tag, uint64_t& skipped, bool& done) {
    if (Status s = bad(what); !s) return s;
    done = !resync(at + 1, tag);
    if (!done) ++skipped;
    return Status::ok();
  }
  /// Moves the cursor to the next record tagged `tag` from `from`; false
  /// when there is none before the end.
  bool resync(size_t from, uint32_t tag) {
    for (size_t at = from; at + 4 <= end_; ++at) {
      c_.seek(at);
      uint32_t t = 0;
      c_.get(t);
      if (t == tag) {
        c_.seek(at);
        return true;
      }
    }
    c_.seek(end_);
    return false;
  }

  const std::string& path_;
  Cursor& c_;
  size_t end_;
  const MapLoadOptions& options_;
  LoadedMap& out_;
};

}  // namespace

Expected<LoadedMap> loadMap(const std::string& path, const MapLoadOptions& options,
                            const alg::RelocalizationParams& relocalization) {
  auto data = readWholeFile(path);
  if (!data) return Error{data.message()};
  return parseMap(*data, path, options, relocalization);
}

Expected<LoadedMap> parseMap(const std::string& bytes, const std::string& path, const MapLoadOptions& options,
                             const alg::RelocalizationParams& relocalization) {
  Cursor c(bytes.data(), bytes.size());
  auto info = parseHeader(path, c);
  if (!info) return Error{info.message()};
  if (Status s = checkTrailer(path, bytes.data(), bytes.size(), *info); !s) return Error{s.message()};
  alg::TsdfParams params = info->tsdf;
  if (options.tsdf) {
    const auto differs = [](double a, double b) { return std::abs(a - b) > 1e-9 * std::max(1.0, std::abs(b)); };
    if (differs(options.tsdf->voxel_size_m, info->tsdf.voxel_size_m) ||
        differs(options.tsdf->truncation_m, info->tsdf.truncation_m)) {
      return Error{
          fmt::format("{}: a map of {} m voxels and {} m truncation; the configuration maps with {} m and {} m "
                      "(tsdf.voxel_size_m, tsdf.truncation_m)",
                      path, info->tsdf.voxel_size_m, info->tsdf.truncation_m, options.tsdf->voxel_size_m,
                      options.tsdf->truncation_m)};
    }
    params = *options.tsdf;
  }
  LoadedMap out{alg::TsdfMap(params), alg::KeyframeDatabase(relocalization), *info, 0, 0};
  out.info.file_bytes = bytes.size();
  RecordReader reader(path, c, bytes.size() - kTrailerBytes, options, out);
  if (Status s = reader.readBlocks(); !s) return Error{s.message()};
  if (Status s = reader.readKeyframes(); !s) return Error{s.message()};
  out.map.markAllChanged(0);
  return out;
}

Expected<MapFileInfo> readMapInfo(const std::string& path) {
  auto data = readWholeFile(path);
  if (!data) return Error{data.message()};
  const std::string& bytes = *data;
  Cursor c(bytes.data(), bytes.size());
  auto info = parseHeader(path, c);
  if (!info) return Error{info.message()};
  if (Status s = checkTrailer(path, bytes.data(), bytes.size(), *info); !s) return Error{s.message()};
  info->file_bytes = bytes.size();
  // Walk the block records by their stored sizes.
  const size_t end = bytes.size() - kTrailerBytes;
  for (uint64_t i = 0; i < info->blocks && end - c.offset() >= kBlockRecordHead; ++i) {
    uint32_t tag = 0, stored = 0;
    c.get(tag);
    c.skip(16);
    c.get(stored);
    c.skip(4);
    if (tag != kBlockTag || stored > end - c.offset()) break;
    c.skip(stored);
    info->block_bytes += stored;
  }
  return info;
}

}  // namespace hxmap::drv
