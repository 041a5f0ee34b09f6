// The OpenVDB export, read back with OpenVDB itself: every observed voxel
// is there with its signed distance, weight and color, at the same place
// in the world as hxmap's voxel center.
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <gtest/gtest.h>

#include "map_export.hpp"
#include "test_data.hpp"

namespace hxmap::rt {
namespace {

TEST(MapExport, AnOpenVdbFileHoldsEveryObservedVoxelWhereHxmapHasIt) {
  alg::TsdfParams p;
  p.voxel_size_m = 0.02;
  p.truncation_m = 0.08;
  alg::TsdfMap map(p);
  // Two blocks, one at negative coordinates; a plane's distances in them.
  for (const alg::BlockKey& key : {alg::BlockKey(0, 0, 0), alg::BlockKey(-2, 1, -1)}) {
    alg::VoxelBlock& b = map.block(static_cast<size_t>(map.findOrAllocate(key)));
    for (int v = 0; v < alg::kBlockVoxels; v += 3) {  // a third of the voxels unobserved
      b.geo[v] = {0.001f * static_cast<float>(v % 80) - 0.04f, 1.0f + static_cast<float>(v % 7)};
      b.color[v] = {static_cast<uint8_t>(v % 256), 128, 255, 0};
    }
  }
  const std::string path = test::tempDir("vdb") + "/map.vdb";
  const auto exported = exportVdb(path, map);
  ASSERT_TRUE(exported) << exported.message();
  const size_t observed = 2 * ((alg::kBlockVoxels + 2) / 3);
  EXPECT_EQ(exported->voxels, observed);

  openvdb::initialize();
  openvdb::io::File file(path);
  file.open();
  auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("sdf"));
  auto weight = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("weight"));
  auto color = openvdb::gridPtrCast<openvdb::Vec3SGrid>(file.readGrid("color"));
  file.close();
  ASSERT_TRUE(sdf && weight && color);
  EXPECT_EQ(sdf->getGridClass(), openvdb::GRID_LEVEL_SET);
  EXPECT_FLOAT_EQ(sdf->background(), 0.08f);
  EXPECT_EQ(sdf->activeVoxelCount(), observed);
  size_t checked = 0;
  for (size_t i = 0; i < map.blockCount(); ++i) {
    const alg::VoxelBlock& b = map.block(i);
    for (int v = 0; v < alg::kBlockVoxels; ++v) {
      if (b.geo[v].weight <= 0) continue;
      const Eigen::Vector3i g =
          map.key(i) * alg::kBlockSide + Eigen::Vector3i(v % alg::kBlockSide, (v / alg::kBlockSide) % alg::kBlockSide,
                                                         v / (alg::kBlockSide * alg::kBlockSide));
      const openvdb::Coord c(g.x(), g.y(), g.z());
      EXPECT_EQ(sdf->tree().getValue(c), b.geo[v].sdf_m);
      EXPECT_EQ(weight->tree().getValue(c), b.geo[v].weight);
      EXPECT_NEAR(color->tree().getValue(c).x(), b.color[v].r / 255.0f, 1e-6f);
      const openvdb::Vec3d w = sdf->transform().indexToWorld(c);
      const Eigen::Vector3f center = map.voxelCenter(g);
      EXPECT_NEAR(w.x(), center.x(), 1e-6);
      EXPECT_NEAR(w.y(), center.y(), 1e-6);
      EXPECT_NEAR(w.z(), center.z(), 1e-6);
      ++checked;
    }
  }
  EXPECT_EQ(checked, observed);
}

}  // namespace
}  // namespace hxmap::rt
