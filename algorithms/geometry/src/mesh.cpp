#include "hxmap/geometry/mesh.hpp"

namespace hxmap::alg {

double TriangleMesh::surfaceArea() const {
  double area = 0.0;
  for (const auto& t : triangles) {
    const Eigen::Vector3d a = vertices[t[0]].cast<double>(), b = vertices[t[1]].cast<double>(),
                          c = vertices[t[2]].cast<double>();
    area += 0.5 * (b - a).cross(c - a).norm();
  }
  return area;
}

void TriangleMesh::append(const TriangleMesh& other) {
  const int offset = static_cast<int>(vertices.size());
  const bool with_colors = !other.colors.empty() || !colors.empty();
  if (with_colors) {
    colors.resize(vertices.size(), Color3(200, 200, 200));
  }
  vertices.insert(vertices.end(), other.vertices.begin(), other.vertices.end());
  if (with_colors) {
    if (other.colors.empty()) {
      colors.resize(vertices.size(), Color3(200, 200, 200));
    } else {
      colors.insert(colors.end(), other.colors.begin(), other.colors.end());
    }
  }
  for (const auto& t : other.triangles) triangles.emplace_back(t.array() + offset);
}

}  // namespace hxmap::alg
