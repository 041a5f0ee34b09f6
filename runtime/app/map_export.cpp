#include "map_export.hpp"

#include <filesystem>
#include <system_error>

#ifdef HXMAP_HAVE_OPENVDB
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#endif

namespace hxmap::rt {

#ifdef HXMAP_HAVE_OPENVDB

Expected<VdbExport> exportVdb(const std::string& path, const alg::TsdfMap& map) {
  openvdb::initialize();
  const double vs = map.voxelSize();
  openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(vs);
  transform->postTranslate(openvdb::Vec3d(0.5 * vs));
  auto sdf = openvdb::FloatGrid::create(map.truncation());
  sdf->setName("sdf");
  sdf->setGridClass(openvdb::GRID_LEVEL_SET);
  auto weight = openvdb::FloatGrid::create(0.0f);
  weight->setName("weight");
  auto color = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
  color->setName("color");
  for (auto* g : {static_cast<openvdb::GridBase*>(sdf.get()), static_cast<openvdb::GridBase*>(weight.get()),
                  static_cast<openvdb::GridBase*>(color.get())}) {
    g->setTransform(transform);
    g->insertMeta("hxmap_frames", openvdb::StringMetadata("world=map"));
  }
  auto sdf_acc = sdf->getAccessor();
  auto weight_acc = weight->getAccessor();
  auto color_acc = color->getAccessor();
  VdbExport out;
  for (size_t b = 0; b < map.blockCount(); ++b) {
    const alg::VoxelBlock& block = map.block(b);
    const alg::BlockKey base = map.key(b) * alg::kBlockSide;
    for (int z = 0; z < alg::kBlockSide; ++z) {
      for (int y = 0; y < alg::kBlockSide; ++y) {
        for (int x = 0; x < alg::kBlockSide; ++x) {
          const int v = alg::VoxelBlock::index(x, y, z);
          if (block.geo[v].weight <= 0) continue;
          const openvdb::Coord c(base.x() + x, base.y() + y, base.z() + z);
          sdf_acc.setValue(c, block.geo[v].sdf_m);
          weight_acc.setValue(c, block.geo[v].weight);
          const alg::VoxelColor& col = block.color[v];
          color_acc.setValue(c, openvdb::Vec3s(col.r / 255.0f, col.g / 255.0f, col.b / 255.0f));
          ++out.voxels;
        }
      }
    }
  }
  const std::string tmp = path + ".tmp";
  try {
    openvdb::GridPtrVec grids{sdf, weight, color};
    openvdb::io::File file(tmp);
    file.write(grids);
    file.close();
  } catch (const std::exception& e) {
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    return Error{path + ": OpenVDB could not write it: " + e.what()};
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) return Error{path + ": cannot rename the temporary file over it: " + ec.message()};
  out.grids = "sdf (level set), weight, color";
  out.bytes = static_cast<size_t>(std::filesystem::file_size(path, ec));
  return out;
}

#else

Expected<VdbExport> exportVdb(const std::string& path, const alg::TsdfMap&) {
  return Error{path +
               ": this hxmap was built without OpenVDB (apt install libopenvdb-dev libboost-dev, then "
               "configure and build again)"};
}

#endif

}  // namespace hxmap::rt
