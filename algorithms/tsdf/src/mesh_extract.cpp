#include "hxmap/tsdf/mesh_extract.hpp"

#include <cmath>
#include <unordered_map>

#include <Eigen/Geometry>

namespace hxmap::alg {

const std::array<std::array<int, 2>, 12> kCubeEdges = {{{0, 1}, {2, 3}, {4, 5}, {6, 7},    // along x
                                                         {0, 2}, {1, 3}, {4, 6}, {5, 7},    // along y
                                                         {0, 4}, {1, 5}, {2, 6}, {3, 7}}};  // along z

namespace {

Eigen::Vector3f cornerPos(int c) {
  return {static_cast<float>(c & 1), static_cast<float>((c >> 1) & 1), static_cast<float>((c >> 2) & 1)};
}

int edgeBetween(int a, int b) {
  for (int e = 0; e < 12; ++e) {
    if ((kCubeEdges[e][0] == a && kCubeEdges[e][1] == b) || (kCubeEdges[e][0] == b && kCubeEdges[e][1] == a)) return e;
  }
  return -1;
}

// The 6 faces, corners counter-clockwise seen from outside the cube.
std::array<std::array<int, 4>, 6> facesCcw() {
  std::array<std::array<int, 4>, 6> faces{};
  int f = 0;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      Eigen::Vector3f n = Eigen::Vector3f::Zero();
      n[axis] = side ? 1.0f : -1.0f;
      std::vector<int> corners;
      for (int c = 0; c < 8; ++c) {
        if (((c >> axis) & 1) == side) corners.push_back(c);
      }
      Eigen::Vector3f center = Eigen::Vector3f::Zero();
      for (int c : corners) center += cornerPos(c) / 4.0f;
      const Eigen::Vector3f u = n.unitOrthogonal(), v = n.cross(u);  // u x v = n
      std::sort(corners.begin(), corners.end(), [&](int a, int b) {
        const Eigen::Vector3f da = cornerPos(a) - center, db = cornerPos(b) - center;
        return std::atan2(da.dot(v), da.dot(u)) < std::atan2(db.dot(v), db.dot(u));
      });
      std::copy(corners.begin(), corners.end(), faces[f].begin());
      ++f;
    }
  }
  return faces;
}

std::vector<std::vector<int>> buildTable() {
  const auto faces = facesCcw();
  std::vector<std::vector<int>> table(256);
  for (int config = 0; config < 256; ++config) {
    auto inside = [&](int c) { return (config >> c) & 1; };
    // next[e] = the edge that the segment starting at edge e ends at.
    std::array<int, 12> next;
    next.fill(-1);
    for (const auto& face : faces) {
      // Walk the face; an entry is an edge going outside -> inside.
      int entries[2], exits[2], ne = 0, nx = 0;
      int entry_pos[2], exit_pos[2];
      for (int i = 0; i < 4; ++i) {
        const int a = face[i], b = face[(i + 1) % 4];
        if (inside(a) == inside(b)) continue;
        if (!inside(a)) {
          entry_pos[ne] = i;
          entries[ne++] = edgeBetween(a, b);
        } else {
          exit_pos[nx] = i;
          exits[nx++] = edgeBetween(a, b);
        }
      }
      // Each negative arc runs from an entry to the next exit (CCW); its
      // segment cuts it off. With 4 crossings this separates the two
      // negative corners.
      for (int k = 0; k < ne; ++k) {
        int best = -1, best_d = 5;
        for (int j = 0; j < nx; ++j) {
          const int d = (exit_pos[j] - entry_pos[k] + 4) % 4;
          if (d < best_d) {
            best_d = d;
            best = j;
          }
        }
        next[entries[k]] = exits[best];
      }
    }
    std::array<bool, 12> used{};
    for (int e = 0; e < 12; ++e) {
      if (next[e] < 0 || used[e]) continue;
      std::vector<int> loop;
      for (int cur = e; !used[cur]; cur = next[cur]) {
        used[cur] = true;
        loop.push_back(cur);
      }
      for (size_t i = 1; i + 1 < loop.size(); ++i) {
        // Loops run counter-clockwise seen from outside the solid, so the fan
        // keeps normals pointing outwards (tested by the sphere's volume).
        table[config].insert(table[config].end(), {loop[0], loop[i], loop[i + 1]});
      }
    }
  }
  return table;
}

const std::vector<std::vector<int>>& table() {
  static const std::vector<std::vector<int>> t = buildTable();
  return t;
}

// Welds vertices by the cube edge they lie on (global voxel coordinates of the
// edge's first corner and its axis).
struct EdgeKeyHash {
  size_t operator()(const Eigen::Vector4i& k) const {
    uint64_t h = static_cast<uint64_t>(k[0]) * 73856093ULL ^ static_cast<uint64_t>(k[1]) * 19349663ULL ^
                 static_cast<uint64_t>(k[2]) * 83492791ULL ^ static_cast<uint64_t>(k[3]) * 2654435761ULL;
    return static_cast<size_t>(h);
  }
};
struct EdgeKeyEq {
  bool operator()(const Eigen::Vector4i& a, const Eigen::Vector4i& b) const { return a == b; }
};

using WeldMap = std::unordered_map<Eigen::Vector4i, int, EdgeKeyHash, EdgeKeyEq>;

// Emits the triangles of the cube whose first corner is grid point g (corner
// values s), grid point i sitting at origin + i * spacing. Vertices are welded
// by cube edge; `on_new_vertex(c0, c1, t)` runs for each new vertex (colors).
template <typename OnNewVertex>
void emitCube(const float s[8], const Eigen::Vector3i& g, const Eigen::Vector3f& origin, float spacing,
              WeldMap& welded, TriangleMesh& mesh, OnNewVertex&& on_new_vertex) {
  int config = 0;
  for (int c = 0; c < 8; ++c) {
    if (s[c] < 0) config |= 1 << c;
  }
  auto vertex = [&](int e) {
    const int c0 = kCubeEdges[e][0], c1 = kCubeEdges[e][1];
    const int axis = e / 4;
    const Eigen::Vector3i g0 = g + Eigen::Vector3i(c0 & 1, (c0 >> 1) & 1, (c0 >> 2) & 1);
    const Eigen::Vector4i key(g0.x(), g0.y(), g0.z(), axis);
    auto it = welded.find(key);
    if (it != welded.end()) return it->second;
    const float t = s[c0] / (s[c0] - s[c1]);
    Eigen::Vector3f p = origin + g0.cast<float>() * spacing;
    p[axis] += t * spacing;
    const int index = static_cast<int>(mesh.vertices.size());
    mesh.vertices.push_back(p);
    on_new_vertex(c0, c1, t);
    welded.emplace(key, index);
    return index;
  };
  const auto& tris = table()[config];
  for (size_t i = 0; i < tris.size(); i += 3) {
    const int a = vertex(tris[i]), b = vertex(tris[i + 1]), c = vertex(tris[i + 2]);
    if (a == b || b == c || a == c) continue;
    mesh.triangles.emplace_back(a, b, c);
  }
}

}  // namespace

const std::vector<int>& marchingCubesTriangles(int configuration) { return table()[configuration & 255]; }

namespace {

// Marching cubes over the cubes of blocks[i] for i in [0, count): each cube
// belongs to the block of its minimum corner.
template <class BlockAt>
TriangleMesh meshBlocks(const TsdfMap& map, const MeshParams& params, size_t count, const BlockAt& block_at) {
  TriangleMesh mesh;
  WeldMap welded;
  const float min_w = std::max(static_cast<float>(params.min_weight), 1e-6f);
  const float vs = map.voxelSize();
  const Eigen::Vector3f voxel_origin = Eigen::Vector3f::Constant(0.5f * vs);  // voxel centers
  for (size_t bi = 0; bi < count; ++bi) {
    const size_t b = block_at(bi);
    const BlockKey key = map.key(b);
    // Neighbour blocks in +x, +y, +z combinations (index by bit mask).
    const VoxelBlock* nb[8];
    for (int m = 0; m < 8; ++m) {
      const int32_t i = map.find(key + BlockKey(m & 1, (m >> 1) & 1, (m >> 2) & 1));
      nb[m] = i >= 0 ? &map.block(i) : nullptr;
    }
    // Corner (x, y, z) of this block's cubes, x, y, z in [0, 8]: its block
    // (or nullptr) and index there.
    auto at = [&](int x, int y, int z, int& index) -> const VoxelBlock* {
      const int m = (x >= kBlockSide) | ((y >= kBlockSide) << 1) | ((z >= kBlockSide) << 2);
      index = VoxelBlock::index(x % kBlockSide, y % kBlockSide, z % kBlockSide);
      return nb[m];
    };
    for (int z = 0; z < kBlockSide; ++z) {
      for (int y = 0; y < kBlockSide; ++y) {
        for (int x = 0; x < kBlockSide; ++x) {
          const VoxelBlock* corner[8];
          int ci[8];
          float s[8];
          bool ok = true, neg = false, pos = false;
          for (int c = 0; c < 8 && ok; ++c) {
            corner[c] = at(x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1), ci[c]);
            ok = corner[c] != nullptr && corner[c]->geo[ci[c]].weight >= min_w;
            if (ok) {
              s[c] = corner[c]->geo[ci[c]].sdf_m;
              neg |= s[c] < 0;
              pos |= s[c] >= 0;
            }
          }
          if (!ok || !neg || !pos) continue;
          const Eigen::Vector3i g = key * kBlockSide + Eigen::Vector3i(x, y, z);
          emitCube(s, g, voxel_origin, vs, welded, mesh, [&](int c0, int c1, float t) {
            if (!params.with_colors) return;
            const VoxelColor& a = corner[c0]->color[ci[c0]];
            const VoxelColor& b = corner[c1]->color[ci[c1]];
            mesh.colors.emplace_back(static_cast<uint8_t>(a.r + t * (b.r - a.r) + 0.5f),  // in [0, 255]: rounds
                                     static_cast<uint8_t>(a.g + t * (b.g - a.g) + 0.5f),
                                     static_cast<uint8_t>(a.b + t * (b.b - a.b) + 0.5f));
          });
        }
      }
    }
  }
  return mesh;
}

}  // namespace

TriangleMesh extractMesh(const TsdfMap& map, const MeshParams& params) {
  return meshBlocks(map, params, map.blockCount(), [](size_t i) { return i; });
}

TriangleMesh extractMesh(const TsdfMap& map, const MeshParams& params, const std::vector<int32_t>& blocks) {
  return meshBlocks(map, params, blocks.size(), [&](size_t i) { return static_cast<size_t>(blocks[i]); });
}

TriangleMesh extractMeshDense(const std::vector<float>& sdf, const Eigen::Vector3i& dims,
                              const Eigen::Vector3f& origin, float spacing) {
  TriangleMesh mesh;
  WeldMap welded;
  auto at = [&](int x, int y, int z) { return sdf[(static_cast<size_t>(z) * dims.y() + y) * dims.x() + x]; };
  for (int z = 0; z + 1 < dims.z(); ++z) {
    for (int y = 0; y + 1 < dims.y(); ++y) {
      for (int x = 0; x + 1 < dims.x(); ++x) {
        float s[8];
        bool ok = true, neg = false, pos = false;
        for (int c = 0; c < 8; ++c) {
          s[c] = at(x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1));
          ok &= std::isfinite(s[c]);
          neg |= s[c] < 0;
          pos |= s[c] >= 0;
        }
        if (!ok || !neg || !pos) continue;
        emitCube(s, Eigen::Vector3i(x, y, z), origin, spacing, welded, mesh, [](int, int, float) {});
      }
    }
  }
  return mesh;
}

}  // namespace hxmap::alg
