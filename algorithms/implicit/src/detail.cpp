#include "hxmap/implicit/detail.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "hxmap/tsdf/mesh_extract.hpp"

namespace hxmap::alg {

namespace {

Eigen::Vector3f centroid(const TriangleMesh& m, const Eigen::Vector3i& t) {
  return (m.vertices[t[0]] + m.vertices[t[1]] + m.vertices[t[2]]) / 3.0f;
}

// The detail's nodes: the hybrid signed distance from the map's trilinear
// SDF; NaN where neither has a value (a cube with such a corner is not
// meshed, as the map's own mesh skips cubes under min_weight).
std::vector<float> hybridSamples(const TsdfMap& map, const RefinedDetail& d, float min_weight) {
  const GridLayout& g = d.grid;
  std::vector<float> sdf(g.nodeCount(), std::numeric_limits<float>::quiet_NaN());
  BlockCache cache(map);
  forEachNode(g, [&](size_t n, const Eigen::Vector3f& p) {
    float now = std::numeric_limits<float>::quiet_NaN();
    if (!cache.sample(p, min_weight, now)) now = std::numeric_limits<float>::quiet_NaN();
    sdf[n] = d.hybridAt(n, now, map.voxelSize());
  });
  return sdf;
}

}  // namespace

float RefinedDetail::hybridAt(size_t n, float now_m, float voxel_m) const {
  const float b = refined_m[n];
  if (!std::isfinite(b)) return now_m;
  if (!std::isfinite(now_m)) return b;
  const float t = snapshot_m[n];
  return std::abs(now_m - t) <= std::abs(b - t) + 0.5f * voxel_m ? b : now_m;
}

TriangleMesh extractHybridMesh(const TsdfMap& map, const MeshParams& params,
                               const std::vector<std::shared_ptr<const RefinedDetail>>& details) {
  std::vector<const RefinedDetail*> live;
  for (const auto& d : details) {
    if (d && !d->empty() && d->refined_m.size() == d->grid.nodeCount() && d->snapshot_m.size() == d->grid.nodeCount()) {
      live.push_back(d.get());
    }
  }
  const TriangleMesh base = extractMesh(map, params);
  if (live.empty()) return base;
  // Index of the last detail whose box holds p, or -1.
  auto owner = [&](const Eigen::Vector3f& p) {
    for (size_t i = live.size(); i-- > 0;) {
      if (live[i]->box.contains(p)) return static_cast<int>(i);
    }
    return -1;
  };

  TriangleMesh out;
  out.vertices = base.vertices;
  out.colors = base.colors;
  for (const auto& t : base.triangles) {
    if (owner(centroid(base, t)) < 0) out.triangles.push_back(t);
  }
  const auto min_weight = static_cast<float>(params.min_weight);
  BlockCache cache(map);
  for (size_t i = 0; i < live.size(); ++i) {
    const RefinedDetail& d = *live[i];
    const TriangleMesh m = extractMeshDense(hybridSamples(map, d, min_weight), d.grid.nodes, d.grid.origin, d.grid.cell);
    TriangleMesh keep;
    keep.vertices = m.vertices;
    for (const auto& t : m.triangles) {
      if (owner(centroid(m, t)) == static_cast<int>(i)) keep.triangles.push_back(t);
    }
    if (keep.triangles.empty()) continue;
    if (params.with_colors) {
      keep.colors.resize(keep.vertices.size(), Color3(128, 128, 128));
      for (size_t v = 0; v < keep.vertices.size(); ++v) {
        Eigen::Vector3f rgb;
        if (cache.sampleColor(keep.vertices[v], rgb)) {
          keep.colors[v] = (rgb.array().round().max(0.0f).min(255.0f)).cast<uint8_t>().matrix();
        }
      }
    }
    out.append(keep);
  }
  // Only the vertices some kept triangle uses.
  std::vector<int> index(out.vertices.size(), -1);
  TriangleMesh compact;
  for (auto t : out.triangles) {
    for (int k = 0; k < 3; ++k) {
      int& j = index[static_cast<size_t>(t[k])];
      if (j < 0) {
        j = static_cast<int>(compact.vertices.size());
        compact.vertices.push_back(out.vertices[static_cast<size_t>(t[k])]);
        if (!out.colors.empty()) compact.colors.push_back(out.colors[static_cast<size_t>(t[k])]);
      }
      t[k] = j;
    }
    compact.triangles.push_back(t);
  }
  return compact;
}

}  // namespace hxmap::alg
