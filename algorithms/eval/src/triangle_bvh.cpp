#include "hxmap/eval/triangle_bvh.hpp"

#include <algorithm>
#include <limits>
#include <numeric>

namespace hxmap::alg {

Eigen::Vector3f closestPointOnTriangle(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b,
                                       const Eigen::Vector3f& c) {
  // Voronoi-region classification of p against the triangle's features.
  const Eigen::Vector3f ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3f bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const Eigen::Vector3f cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const float denom = va + vb + vc;
  if (!(std::abs(denom) > 0)) return a;  // degenerate triangle
  const float v = vb / denom, w = vc / denom;
  return a + ab * v + ac * w;
}

TriangleBvh::TriangleBvh(const TriangleMesh& mesh) {
  const size_t n = mesh.triangles.size();
  a_.reserve(n);
  b_.reserve(n);
  c_.reserve(n);
  for (const auto& t : mesh.triangles) {
    a_.push_back(mesh.vertices[t[0]]);
    b_.push_back(mesh.vertices[t[1]]);
    c_.push_back(mesh.vertices[t[2]]);
  }
  order_.resize(n);
  std::iota(order_.begin(), order_.end(), 0);
  if (n > 0) {
    nodes_.reserve(2 * n / 2 + 1);
    build(0, static_cast<int32_t>(n));
  }
}

int32_t TriangleBvh::build(int32_t first, int32_t count) {
  Node node;
  node.lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  node.hi = -node.lo;
  Eigen::Vector3f clo = node.lo, chi = node.hi;
  for (int32_t k = first; k < first + count; ++k) {
    const int32_t t = order_[k];
    node.lo = node.lo.cwiseMin(a_[t]).cwiseMin(b_[t]).cwiseMin(c_[t]);
    node.hi = node.hi.cwiseMax(a_[t]).cwiseMax(b_[t]).cwiseMax(c_[t]);
    const Eigen::Vector3f centroid = (a_[t] + b_[t] + c_[t]) / 3.0f;
    clo = clo.cwiseMin(centroid);
    chi = chi.cwiseMax(centroid);
  }
  const int32_t index = static_cast<int32_t>(nodes_.size());
  nodes_.push_back(node);
  if (count <= 4) {
    nodes_[index].first = first;
    nodes_[index].count = count;
    return index;
  }
  int axis = 0;
  (chi - clo).maxCoeff(&axis);
  const int32_t mid = first + count / 2;
  std::nth_element(order_.begin() + first, order_.begin() + mid, order_.begin() + first + count,
                   [&](int32_t x, int32_t y) {
                     return a_[x][axis] + b_[x][axis] + c_[x][axis] < a_[y][axis] + b_[y][axis] + c_[y][axis];
                   });
  const int32_t left = build(first, mid - first);
  const int32_t right = build(mid, first + count - mid);
  nodes_[index].left = left;
  nodes_[index].right = right;
  return index;
}

namespace {
float boxDistanceSq(const Eigen::Vector3f& p, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  const Eigen::Vector3f d = (lo - p).cwiseMax(p - hi).cwiseMax(Eigen::Vector3f::Zero());
  return d.squaredNorm();
}
}  // namespace

float TriangleBvh::distance(const Eigen::Vector3f& p, float max_distance) const {
  if (nodes_.empty()) return std::numeric_limits<float>::infinity();
  float best_sq = max_distance < 1e15f ? max_distance * max_distance : std::numeric_limits<float>::max();
  int32_t stack[128];
  int sp = 0;
  stack[sp++] = 0;
  while (sp > 0) {
    const Node& node = nodes_[stack[--sp]];
    if (boxDistanceSq(p, node.lo, node.hi) >= best_sq) continue;
    if (node.left < 0) {
      for (int32_t k = node.first; k < node.first + node.count; ++k) {
        const int32_t t = order_[k];
        best_sq = std::min(best_sq, (closestPointOnTriangle(p, a_[t], b_[t], c_[t]) - p).squaredNorm());
      }
      continue;
    }
    // Visit the nearer child first (pushed last).
    const float dl = boxDistanceSq(p, nodes_[node.left].lo, nodes_[node.left].hi);
    const float dr = boxDistanceSq(p, nodes_[node.right].lo, nodes_[node.right].hi);
    if (dl < dr) {
      stack[sp++] = node.right;
      stack[sp++] = node.left;
    } else {
      stack[sp++] = node.left;
      stack[sp++] = node.right;
    }
  }
  return std::sqrt(best_sq);
}

float TriangleBvh::raycast(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float t_min, float t_max) const {
  if (nodes_.empty()) return t_max;
  const Eigen::Vector3f inv = dir.cwiseInverse();
  float best = t_max;
  int32_t stack[128];
  int sp = 0;
  stack[sp++] = 0;
  while (sp > 0) {
    const Node& node = nodes_[stack[--sp]];
    const Eigen::Vector3f t0 = (node.lo - origin).cwiseProduct(inv), t1 = (node.hi - origin).cwiseProduct(inv);
    const float tn = std::max(t0.cwiseMin(t1).maxCoeff(), t_min);
    const float tf = std::min(t0.cwiseMax(t1).minCoeff(), best);
    if (!(tn <= tf)) continue;
    if (node.left >= 0) {
      stack[sp++] = node.left;
      stack[sp++] = node.right;
      continue;
    }
    for (int32_t k = node.first; k < node.first + node.count; ++k) {
      const int32_t t = order_[k];
      // Moller-Trumbore.
      const Eigen::Vector3f e1 = b_[t] - a_[t], e2 = c_[t] - a_[t];
      const Eigen::Vector3f pv = dir.cross(e2);
      const float det = e1.dot(pv);
      if (std::abs(det) < 1e-12f) continue;
      const float inv_det = 1.0f / det;
      const Eigen::Vector3f tv = origin - a_[t];
      const float u = tv.dot(pv) * inv_det;
      if (u < 0 || u > 1) continue;
      const Eigen::Vector3f qv = tv.cross(e1);
      const float v = dir.dot(qv) * inv_det;
      if (v < 0 || u + v > 1) continue;
      const float hit = e2.dot(qv) * inv_det;
      if (hit > t_min && hit < best) best = hit;
    }
  }
  return best;
}

PointKdTree::PointKdTree(std::vector<Eigen::Vector3f> points) : pts_(std::move(points)) {
  build(0, static_cast<int>(pts_.size()), 0);
}

void PointKdTree::build(int lo, int hi, int depth) {
  if (hi - lo <= 1) return;
  const int axis = depth % 3;
  const int mid = (lo + hi) / 2;
  std::nth_element(pts_.begin() + lo, pts_.begin() + mid, pts_.begin() + hi,
                   [axis](const Eigen::Vector3f& a, const Eigen::Vector3f& b) { return a[axis] < b[axis]; });
  build(lo, mid, depth + 1);
  build(mid + 1, hi, depth + 1);
}

void PointKdTree::search(int lo, int hi, int depth, const Eigen::Vector3f& p, float& best_sq) const {
  if (lo >= hi) return;
  const int axis = depth % 3;
  const int mid = (lo + hi) / 2;
  best_sq = std::min(best_sq, (pts_[mid] - p).squaredNorm());
  const float d = p[axis] - pts_[mid][axis];
  if (d < 0) {
    search(lo, mid, depth + 1, p, best_sq);
    if (d * d < best_sq) search(mid + 1, hi, depth + 1, p, best_sq);
  } else {
    search(mid + 1, hi, depth + 1, p, best_sq);
    if (d * d < best_sq) search(lo, mid, depth + 1, p, best_sq);
  }
}

float PointKdTree::distance(const Eigen::Vector3f& p) const {
  float best = std::numeric_limits<float>::max();
  search(0, static_cast<int>(pts_.size()), 0, p, best);
  return pts_.empty() ? std::numeric_limits<float>::infinity() : std::sqrt(best);
}

}  // namespace hxmap::alg
