#include <map>

#include <gtest/gtest.h>

#include "hxmap/tsdf/mesh_extract.hpp"

namespace hxmap::alg {
namespace {

TEST(MarchingCubesTable, OnlyCrossingEdgesAndClosedLoops) {
  for (int config = 0; config < 256; ++config) {
    const auto& tris = marchingCubesTriangles(config);
    EXPECT_EQ(tris.size() % 3, 0u);
    for (int e : tris) {
      const bool a = (config >> kCubeEdges[e][0]) & 1, b = (config >> kCubeEdges[e][1]) & 1;
      EXPECT_NE(a, b) << "configuration " << config << " uses edge " << e << " without a sign change";
    }
    if (config == 0 || config == 255) {
      EXPECT_TRUE(tris.empty());
    }
  }
  EXPECT_EQ(marchingCubesTriangles(1).size(), 3u);  // one corner inside: one triangle
}

TEST(MarchingCubes, SphereIsWatertightOutwardAndAccurate) {
  const float r = 0.3f, h = 0.02f;
  const int n = 40;
  const Eigen::Vector3f origin = Eigen::Vector3f::Constant(-0.4f);
  std::vector<float> sdf(n * n * n);
  for (int z = 0; z < n; ++z) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        sdf[(z * n + y) * n + x] = (origin + Eigen::Vector3f(x, y, z) * h).norm() - r;
      }
    }
  }
  const TriangleMesh m = extractMeshDense(sdf, {n, n, n}, origin, h);
  ASSERT_GT(m.triangles.size(), 1000u);
  double worst = 0, volume = 0;
  for (const auto& v : m.vertices) worst = std::max(worst, std::abs(static_cast<double>(v.norm() - r)));
  EXPECT_LT(worst, 0.1 * h);  // linear interpolation of an exact SDF
  std::map<std::pair<int, int>, int> edges;
  for (const auto& t : m.triangles) {
    volume += m.vertices[t[0]].cast<double>().dot(m.vertices[t[1]].cast<double>().cross(m.vertices[t[2]].cast<double>())) / 6.0;
    for (int k = 0; k < 3; ++k) {
      const int a = t[k], b = t[(k + 1) % 3];
      ++edges[{std::min(a, b), std::max(a, b)}];
    }
  }
  for (const auto& [e, count] : edges) ASSERT_EQ(count, 2) << "edge shared by " << count << " triangles";
  // Positive signed volume: triangles counter-clockwise seen from outside.
  EXPECT_NEAR(volume, 4.0 / 3.0 * M_PI * r * r * r, 0.02 * 4.0 / 3.0 * M_PI * r * r * r);
}

}  // namespace
}  // namespace hxmap::alg
