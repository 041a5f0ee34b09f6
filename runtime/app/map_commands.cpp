// hxmap map info|mesh|export: what a saved map file holds, its mesh, and
// the TSDF in a format other tools open.
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "hxmap/dataset/ply.hpp"
#include "hxmap/mapfile/map_file.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "map_export.hpp"

namespace hxmap::rt {

namespace {

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// Voxel statistics of a loaded map: observed voxels, those near the
/// surface, and the bounds of the observed ones.
std::string mapStatistics(const alg::TsdfMap& map) {
  size_t observed = 0, surface = 0;
  Eigen::AlignedBox3f box;
  const float near = static_cast<float>(map.voxelSize());
  for (size_t i = 0; i < map.blockCount(); ++i) {
    const alg::VoxelBlock& b = map.block(i);
    bool any = false;
    for (int v = 0; v < alg::kBlockVoxels; ++v) {
      if (b.geo[v].weight <= 0) continue;
      ++observed;
      surface += std::abs(b.geo[v].sdf_m) < near;
      any = true;
    }
    if (any) {
      const Eigen::Vector3f lo = map.key(i).cast<float>() * map.blockSize();
      box.extend(lo);
      box.extend(lo + Eigen::Vector3f::Constant(map.blockSize()));
    }
  }
  std::string text = fmt::format("voxels: {} allocated, {} observed, {} within a voxel of the surface\n",
                                 map.blockCount() * alg::kBlockVoxels, observed, surface);
  if (!box.isEmpty()) {
    const Eigen::Vector3f lo = box.min(), hi = box.max();
    text += fmt::format("bounds (m): x {:.2f} .. {:.2f}, y {:.2f} .. {:.2f}, z {:.2f} .. {:.2f}\n", lo.x(), hi.x(),
                        lo.y(), hi.y(), lo.z(), hi.z());
  }
  return text;
}

/// The map file, or nothing with the error logged.
std::optional<drv::LoadedMap> loadLogged(const MapOptions& o) {
  drv::MapLoadOptions lo;
  lo.skip_bad = o.skip_bad;
  auto loaded = drv::loadMap(o.file, lo);
  if (!loaded) {
    spdlog::error("{}", loaded.message());
    return std::nullopt;
  }
  return std::move(*loaded);
}

int infoCommand(const MapOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  auto loaded = loadLogged(o);
  if (!loaded) return 1;
  const double load_s = secondsSince(t0);
  const drv::MapFileInfo& i = loaded->info;
  const double raw = static_cast<double>(i.blocks) * alg::kBlockVoxels * 24;
  std::string text = fmt::format(
      "file: {} ({:.2f} MiB), format version {}\n"
      "tsdf: voxel {} m, truncation {} m, weight cap {}, blocks of {}^3 voxels\n"
      "frames: {}\n"
      "blocks: {} ({:.2f} MiB of voxels stored in {:.2f} MiB: {:.1f}x)\n"
      "keyframes: {} (for relocalization)\n",
      o.file, static_cast<double>(i.file_bytes) / (1 << 20), i.version, i.tsdf.voxel_size_m, i.tsdf.truncation_m,
      i.tsdf.max_weight, alg::kBlockSide, i.frames, i.blocks, raw / (1 << 20),
      static_cast<double>(i.block_bytes) / (1 << 20), i.block_bytes > 0 ? raw / static_cast<double>(i.block_bytes) : 0,
      i.keyframes);
  text += mapStatistics(loaded->map);
  if (loaded->skipped_blocks + loaded->skipped_keyframes > 0) {
    text +=
        fmt::format("skipped (corrupt): {} blocks, {} keyframes\n", loaded->skipped_blocks, loaded->skipped_keyframes);
  }
  text += fmt::format("load: {:.3f} s\n", load_s);
  std::fputs(text.c_str(), stdout);
  return 0;
}

int meshCommand(const MapOptions& o, const alg::MeshParams& params) {
  auto loaded = loadLogged(o);
  if (!loaded) return 1;
  const alg::TriangleMesh mesh = alg::extractMesh(loaded->map, params);
  if (auto s = drv::writePly(o.out, mesh); !s) {
    spdlog::error("{}", s.message());
    return 1;
  }
  std::printf("mesh: %s (%zu vertices, %zu triangles)\n", o.out.c_str(), mesh.vertices.size(), mesh.triangles.size());
  return 0;
}

int exportCommand(const MapOptions& o) {
  if (o.format != "vdb") {
    spdlog::error("map export: unknown --format '{}' (vdb)", o.format);
    return 2;
  }
  auto loaded = loadLogged(o);
  if (!loaded) return 1;
  const auto t0 = std::chrono::steady_clock::now();
  auto exported = exportVdb(o.out, loaded->map);
  if (!exported) {
    spdlog::error("{}", exported.message());
    return 1;
  }
  std::printf("export: %s (OpenVDB: %s, %zu voxels, %.2f MiB in %.2f s)\n", o.out.c_str(), exported->grids.c_str(),
              exported->voxels, static_cast<double>(exported->bytes) / (1 << 20), secondsSince(t0));
  return 0;
}

}  // namespace

int mapCommand(const MapOptions& o) {
  if (o.action == "info") return infoCommand(o);
  if (o.action == "mesh" || o.action == "export") {
    if (o.out.empty()) {
      spdlog::error("map {}: --out is required", o.action);
      return 2;
    }
  }
  if (o.action == "mesh") {
    alg::MeshParams params;
    if (!o.config.empty()) {
      auto c = loadConfig(o.config);
      if (!c) {
        spdlog::error("{}", c.message());
        return 2;
      }
      params = c->mesh;
    }
    return meshCommand(o, params);
  }
  if (o.action == "export") return exportCommand(o);
  spdlog::error("map: unknown action '{}' (info, mesh or export)", o.action);
  return 2;
}

}  // namespace hxmap::rt
