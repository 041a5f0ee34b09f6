// Bounding volume hierarchy over a mesh's triangles: exact point-to-surface
// distances (nearest triangle) and ray casts. Immutable after construction,
// so queries are thread safe.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "hxmap/geometry/mesh.hpp"

namespace hxmap::alg {

class TriangleBvh {
 public:
  explicit TriangleBvh(const TriangleMesh& mesh);

  /// Distance from p to the nearest point of the surface (meters); infinity
  /// for an empty mesh. `max_distance` prunes the search: a result larger
  /// than it may be returned as any value > max_distance.
  float distance(const Eigen::Vector3f& p, float max_distance = 1e30f) const;

  /// Distance along the ray (origin + t * dir, |dir| = 1) to the first hit with
  /// t in (t_min, t_max); returns t_max when nothing is hit.
  float raycast(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float t_min, float t_max) const;

 private:
  struct Node {
    Eigen::Vector3f lo, hi;
    int32_t left = -1, right = -1;  ///< children, or -1 for a leaf
    int32_t first = 0, count = 0;   ///< leaf range in order_
  };
  int32_t build(int32_t first, int32_t count);

  std::vector<Eigen::Vector3f> a_, b_, c_;  ///< triangle corners
  std::vector<int32_t> order_;
  std::vector<Node> nodes_;
};

/// Closest point to p on triangle (a, b, c).
Eigen::Vector3f closestPointOnTriangle(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b,
                                       const Eigen::Vector3f& c);

/// Nearest-neighbour search over a point set (k-d tree), for the
/// point-to-sampled-point metric variant.
class PointKdTree {
 public:
  explicit PointKdTree(std::vector<Eigen::Vector3f> points);
  float distance(const Eigen::Vector3f& p) const;

 private:
  void build(int lo, int hi, int depth);
  void search(int lo, int hi, int depth, const Eigen::Vector3f& p, float& best_sq) const;
  std::vector<Eigen::Vector3f> pts_;
};

}  // namespace hxmap::alg
