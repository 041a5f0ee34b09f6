#include "hxmap/tsdf/map_regions.hpp"

#include <algorithm>

#include "hxmap/tsdf/mesh_extract.hpp"

namespace hxmap::alg {

namespace {

int floorDiv(int a, int b) { return a / b - ((a % b != 0) && ((a < 0) != (b < 0))); }

bool keyLess(const Eigen::Vector3i& a, const Eigen::Vector3i& b) {
  return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
}

}  // namespace

RegionKey regionOf(const BlockKey& block, int region_blocks) {
  return {floorDiv(block.x(), region_blocks), floorDiv(block.y(), region_blocks), floorDiv(block.z(), region_blocks)};
}

std::vector<RegionKey> changedRegions(const TsdfMap& map, uint64_t revision, int region_blocks) {
  std::vector<RegionKey> regions;
  for (const int32_t b : map.changedSince(revision)) {
    const BlockKey& k = map.key(static_cast<size_t>(b));
    const RegionKey r = regionOf(k, region_blocks);
    // A block on the region's -x/-y/-z face is also in the layer beyond
    // the +x/+y/+z faces that the neighbours' marching cubes read.
    const Eigen::Vector3i first = (k.array() == (r * region_blocks).array()).cast<int>();
    for (int dz = 0; dz <= first.z(); ++dz) {
      for (int dy = 0; dy <= first.y(); ++dy) {
        for (int dx = 0; dx <= first.x(); ++dx) regions.push_back(r - RegionKey(dx, dy, dz));
      }
    }
  }
  std::sort(regions.begin(), regions.end(), keyLess);
  regions.erase(std::unique(regions.begin(), regions.end()), regions.end());
  return regions;
}

std::vector<RegionKey> occupiedRegions(const TsdfMap& map, int region_blocks) {
  std::vector<RegionKey> regions;
  regions.reserve(map.blockCount());
  // Neighbouring blocks mostly share a region: the sort below gets far
  // fewer entries than blocks (hundreds of thousands out on a long run).
  auto add = [&](const BlockKey& k) {
    const RegionKey r = regionOf(k, region_blocks);
    if (regions.empty() || regions.back() != r) regions.push_back(r);
  };
  for (size_t b = 0; b < map.blockCount(); ++b) add(map.key(b));
  // Blocks out of memory (a memory budget) are still part of the map.
  map.blocksElsewhere().forEach(add);
  std::sort(regions.begin(), regions.end(), keyLess);
  regions.erase(std::unique(regions.begin(), regions.end()), regions.end());
  return regions;
}

std::vector<BlockKey> regionBlocksElsewhere(const TsdfMap& map, const RegionKey& region, int region_blocks) {
  std::vector<BlockKey> out;
  if (map.blocksElsewhere().empty()) return out;
  const BlockKey lo = region * region_blocks;
  for (int z = 0; z <= region_blocks; ++z) {
    for (int y = 0; y <= region_blocks; ++y) {
      for (int x = 0; x <= region_blocks; ++x) {
        if (map.heldElsewhere(lo + BlockKey(x, y, z))) out.push_back(lo + BlockKey(x, y, z));
      }
    }
  }
  return out;
}

size_t readBlocksInto(TsdfMap& local, const std::vector<BlockKey>& keys, const BlockReader& read) {
  size_t unread = 0;
  for (const BlockKey& k : keys) {
    VoxelBlock b;
    if (read && read(k, b)) {
      local.block(static_cast<size_t>(local.findOrAllocate(k))) = b;
    } else {
      ++unread;
    }
  }
  return unread;
}

TsdfMap copyRegions(const TsdfMap& map, const std::vector<RegionKey>& regions, int region_blocks) {
  TsdfMap out(map.params());
  for (const RegionKey& r : regions) {
    const BlockKey lo = r * region_blocks;
    for (int z = 0; z <= region_blocks; ++z) {
      for (int y = 0; y <= region_blocks; ++y) {
        for (int x = 0; x <= region_blocks; ++x) {
          const BlockKey k = lo + BlockKey(x, y, z);
          const int32_t b = map.find(k);
          if (b < 0 || out.find(k) >= 0) continue;
          out.block(static_cast<size_t>(out.findOrAllocate(k))) = map.block(static_cast<size_t>(b));
        }
      }
    }
  }
  return out;
}

TriangleMesh regionMesh(const TsdfMap& map, const RegionKey& region, int region_blocks, const MeshParams& params) {
  std::vector<int32_t> blocks;
  const BlockKey lo = region * region_blocks;
  for (int z = 0; z < region_blocks; ++z) {
    for (int y = 0; y < region_blocks; ++y) {
      for (int x = 0; x < region_blocks; ++x) {
        const int32_t b = map.find(lo + BlockKey(x, y, z));
        if (b >= 0) blocks.push_back(b);
      }
    }
  }
  return extractMesh(map, params, blocks);
}

std::vector<TriangleMesh> splitMesh(const TriangleMesh& mesh, size_t max_triangles) {
  max_triangles = std::max<size_t>(max_triangles, 1);
  std::vector<TriangleMesh> parts;
  if (mesh.triangles.size() <= max_triangles) {
    if (!mesh.triangles.empty()) parts.push_back(mesh);
    return parts;
  }
  const bool colors = mesh.colors.size() == mesh.vertices.size();
  std::vector<int> remap(mesh.vertices.size(), -1);
  for (size_t begin = 0; begin < mesh.triangles.size(); begin += max_triangles) {
    const size_t end = std::min(begin + max_triangles, mesh.triangles.size());
    TriangleMesh part;
    std::vector<int> used;
    for (size_t t = begin; t < end; ++t) {
      Eigen::Vector3i tri;
      for (int c = 0; c < 3; ++c) {
        const int v = mesh.triangles[t][c];
        if (remap[static_cast<size_t>(v)] < 0) {
          remap[static_cast<size_t>(v)] = static_cast<int>(part.vertices.size());
          part.vertices.push_back(mesh.vertices[static_cast<size_t>(v)]);
          if (colors) part.colors.push_back(mesh.colors[static_cast<size_t>(v)]);
          used.push_back(v);
        }
        tri[c] = remap[static_cast<size_t>(v)];
      }
      part.triangles.push_back(tri);
    }
    for (const int v : used) remap[static_cast<size_t>(v)] = -1;
    parts.push_back(std::move(part));
  }
  return parts;
}

}  // namespace hxmap::alg
