// Triangle mesh shared by meshing, the synthetic scenes and evaluation.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace hxmap::alg {

using Color3 = Eigen::Matrix<uint8_t, 3, 1>;

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;  ///< world frame, meters
  std::vector<Color3> colors;             ///< empty or one per vertex
  std::vector<Eigen::Vector3i> triangles; ///< counter-clockwise seen from outside

  bool empty() const { return triangles.empty(); }
  double surfaceArea() const;
  /// Appends `other`, offsetting its indices.
  void append(const TriangleMesh& other);
};

}  // namespace hxmap::alg
