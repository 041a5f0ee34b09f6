// Map files (.hxm): a TSDF map and the keyframe database that relocalizes
// in it, saved to continue mapping later (hxmap run --save-map / --load-map)
// or to inspect, mesh and export (hxmap map info|mesh|export).
//
// Layout, little-endian (docs/usage.md has the byte-level table):
//   header   magic "HXMAPTSD", format version, the TSDF parameters that
//            give voxels their meaning (voxel size, truncation, weight cap,
//            block side, voxel record size), the frame conventions, counts
//            of blocks and keyframes, and a CRC-32C of the header;
//   blocks   one record per allocated block: a record tag, the block key,
//            the stored size, a CRC-32C of the stored bytes, and the 8^3
//            voxels (signed distance, weight, color, statistics) compressed
//            with zstd;
//   keyframes one record per keyframe: id, pose T_world_cam, descriptors
//            and their camera-frame points, with a CRC-32C;
//   trailer  magic "HXMAPEND" and the counts again: a file cut short is
//            told apart from a complete one.
//
// Writing is atomic: a temporary file beside the target is written,
// flushed to disk, and renamed over it; a process killed mid-write leaves
// the previous file as it was.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/relocalization/keyframe_database.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::drv {

/// The format this build writes and reads.
constexpr uint32_t kMapFileVersion = 1;

/// The frames a map file's coordinates are in (stored in its header): the
/// map's world frame, and cameras as optical frames (x right, y down,
/// z forward), as in hxmap's trajectories.
inline constexpr const char* kMapFileFrames = "world=map;camera=optical(x-right,y-down,z-forward)";

/// What a map file's header and trailer say, and what reading it found.
struct MapFileInfo {
  uint32_t version = 0;
  alg::TsdfParams tsdf;  ///< voxel size, truncation and weight cap (the rest: defaults)
  std::string frames;
  uint64_t blocks = 0;     ///< in the file
  uint64_t keyframes = 0;  ///< in the file
  uint64_t file_bytes = 0;
  uint64_t block_bytes = 0;  ///< compressed voxel data (of the records read)
};

struct MapLoadOptions {
  /// A block or keyframe whose checksum does not match is skipped and
  /// counted instead of failing the load.
  bool skip_bad = false;
  /// The parameters the caller maps with (hxmap run --load-map): the loaded
  /// map takes them, and a file of another voxel size or truncation is an
  /// error naming both. Unset: the file's, with defaults for the rest.
  std::optional<alg::TsdfParams> tsdf;
};

struct LoadedMap {
  alg::TsdfMap map;
  alg::KeyframeDatabase keyframes;
  MapFileInfo info;
  uint64_t skipped_blocks = 0;     ///< with skip_bad: corrupt blocks left out
  uint64_t skipped_keyframes = 0;  ///< with skip_bad: corrupt keyframes left out
};

/// What saving wrote.
struct MapSaveStats {
  uint64_t blocks = 0;
  uint64_t keyframes = 0;
  uint64_t bytes = 0;
};

/// Saves the map and (optional) keyframe database to `path`, atomically.
/// The TSDF parameters stored are the map's.
Expected<MapSaveStats> saveMap(const std::string& path, const alg::TsdfMap& map,
                               const alg::KeyframeDatabase* keyframes = nullptr);

/// Loads a map file. Errors name the file and the byte offset at fault: a
/// missing or unreadable file, another format or version, a truncated
/// file, a corrupt block or keyframe (unless options.skip_bad). The
/// keyframe database gets `relocalization` as its parameters.
Expected<LoadedMap> loadMap(const std::string& path, const MapLoadOptions& options = {},
                            const alg::RelocalizationParams& relocalization = {});

/// loadMap on a file's bytes; `path` names it in errors.
Expected<LoadedMap> parseMap(const std::string& bytes, const std::string& path, const MapLoadOptions& options = {},
                             const alg::RelocalizationParams& relocalization = {});

/// A map file's header and trailer, checked, and the bytes of voxel data
/// (records are stepped over by their stored sizes, not decompressed).
Expected<MapFileInfo> readMapInfo(const std::string& path);

/// CRC-32C (Castagnoli) of `n` bytes, continuing from `crc` (0 to start).
uint32_t crc32c(const void* data, size_t n, uint32_t crc = 0);

}  // namespace hxmap::drv
