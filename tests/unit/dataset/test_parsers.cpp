#include <cstring>
#include <fstream>

#include <gtest/gtest.h>

#include "hxmap/dataset/parsers.hpp"
#include "hxmap/dataset/ply.hpp"

namespace hxmap::drv {
namespace {

TEST(TumList, ParsesWithCommentsAndBlankLines) {
  auto r = parseTumList("# color images\n\n1305031102.175304 rgb/a.png\r\n1305031102.211214 rgb/b.png\n", "rgb.txt");
  ASSERT_TRUE(r) << r.message();
  ASSERT_EQ(r->entries.size(), 2u);
  EXPECT_EQ(r->entries[0].stamp_ns, 1305031102175304000LL);
  EXPECT_EQ(r->entries[1].path, "rgb/b.png");
  EXPECT_EQ(r->entries[1].line, 4);
}

TEST(TumList, BadLineNamesFileAndLine) {
  auto r = parseTumList("# c\n1.0 a.png\nnot_a_time b.png\n", "rgb.txt");
  ASSERT_FALSE(r);
  EXPECT_EQ(r.message(), "rgb.txt:3: bad timestamp 'not_a_time'");
  auto s = parseTumList("1.0 a.png\n2.0\n", "depth.txt");
  ASSERT_FALSE(s);
  EXPECT_NE(s.message().find("depth.txt:2: expected 'timestamp filename'"), std::string::npos);
}

TEST(TumList, SkipModeCountsBadLines) {
  auto r = parseTumList("1.0 a.png\nxx b.png\n3.0 c.png\n", "rgb.txt", {true});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->entries.size(), 2u);
  ASSERT_EQ(r->skipped.size(), 1u);
  EXPECT_NE(r->skipped[0].find("rgb.txt:2"), std::string::npos);
}

TEST(TumList, EmptyListIsAnError) {
  auto r = parseTumList("# only comments\n\n", "rgb.txt");
  ASSERT_FALSE(r);
  EXPECT_NE(r.message().find("rgb.txt: the list has no entries"), std::string::npos);
}

TEST(TumTrajectory, ParsesAndValidates) {
  auto r = parseTumTrajectory("# gt\n1.0 1 2 3 0 0 0 1\n", "gt.txt");
  ASSERT_TRUE(r) << r.message();
  EXPECT_EQ(r->poses[0].T_world_cam.translation(), Eigen::Vector3d(1, 2, 3));
  auto nan = parseTumTrajectory("1.0 nan 2 3 0 0 0 1\n", "gt.txt");
  ASSERT_FALSE(nan);
  EXPECT_EQ(nan.message(), "gt.txt:1: a value is not a finite number");
  auto q = parseTumTrajectory("1.0 1 2 3 0 0 0 2\n", "gt.txt");
  ASSERT_FALSE(q);
  EXPECT_NE(q.message().find("gt.txt:1: quaternion norm 2.0000 is not 1"), std::string::npos);
  auto n = parseTumTrajectory("1.0 1 2 3 0 0 1\n", "gt.txt");
  ASSERT_FALSE(n);
  EXPECT_NE(n.message().find("expected 8 values"), std::string::npos);
}

TEST(MatrixTrajectory, ParsesAndRejectsNonRigid) {
  auto ok = parseMatrixTrajectory("1 0 0 1 0 1 0 2 0 0 1 3 0 0 0 1\n", "traj.txt", 100);
  ASSERT_TRUE(ok) << ok.message();
  EXPECT_EQ(ok->poses[0].T_world_cam.translation(), Eigen::Vector3d(1, 2, 3));
  auto scaled = parseMatrixTrajectory("1 0 0 1 0 1 0 2 0 0 1 3 0 0 0 1\n2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n",
                                      "traj.txt", 100);
  ASSERT_FALSE(scaled);
  EXPECT_NE(scaled.message().find("traj.txt:2: the matrix is not a rigid transform"), std::string::npos);
  auto nan = parseMatrixTrajectory("1 0 0 nan 0 1 0 2 0 0 1 3 0 0 0 1\n", "traj.txt", 100);
  ASSERT_FALSE(nan);
  EXPECT_NE(nan.message().find("traj.txt:1: value 4 is not a finite number"), std::string::npos);
}

TEST(TrajectoryFormat, RoundTrip) {
  Trajectory t(1);
  t[0].stamp_ns = 1305031102175304000LL;
  t[0].T_world_cam.translation() = Eigen::Vector3d(0.1, -0.2, 0.3);
  auto back = parseTumTrajectory(formatTumTrajectory(t), "x");
  ASSERT_TRUE(back);
  EXPECT_EQ(back->poses[0].stamp_ns, t[0].stamp_ns);
  EXPECT_LT((back->poses[0].T_world_cam.translation() - t[0].T_world_cam.translation()).norm(), 1e-6);
}

TEST(Ply, RoundTripAndCorruption) {
  alg::TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.colors = {{255, 0, 0}, {0, 255, 0}, {0, 0, 255}};
  m.triangles = {{0, 1, 2}};
  const std::string path = ::testing::TempDir() + "/hxmap_roundtrip.ply";
  ASSERT_TRUE(writePly(path, m));
  auto back = readPly(path);
  ASSERT_TRUE(back) << back.message();
  EXPECT_EQ(back->vertices[1], m.vertices[1]);
  EXPECT_EQ(back->colors[2], m.colors[2]);
  EXPECT_EQ(back->triangles[0], m.triangles[0]);
  {
    // Normals follow x, y, z: the triangle is counter-clockwise seen from +z.
    std::ifstream in(path, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), {});
    ASSERT_NE(bytes.find("property float x\nproperty float y\nproperty float z\nproperty float nx\n"
                         "property float ny\nproperty float nz\n"),
              std::string::npos);
    const size_t body = bytes.find("end_header\n") + 11;
    for (int v = 0; v < 3; ++v) {
      float n[3];
      std::memcpy(n, bytes.data() + body + static_cast<size_t>(v) * 27 + 12, sizeof n);
      EXPECT_EQ(n[0], 0.0f);
      EXPECT_EQ(n[1], 0.0f);
      EXPECT_EQ(n[2], 1.0f);
    }
  }
  auto truncated = parsePly("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                            "property float y\nproperty float z\nend_header\n\x01\x02",
                            "t.ply");
  ASSERT_FALSE(truncated);
  EXPECT_EQ(truncated.message(), "t.ply: PLY body is truncated or malformed");
  auto bad_index = parsePly("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                            "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                            "0 0 0\n3 0 1 2\n",
                            "i.ply");
  ASSERT_FALSE(bad_index);
  EXPECT_NE(bad_index.message().find("missing vertex"), std::string::npos);
}

}  // namespace
}  // namespace hxmap::drv
