// Map files: a saved map loads back bit for bit; a truncated or corrupt
// file, another version and another voxel size are clear errors naming the
// file (and the offset); a corrupt block can be skipped; a writer killed
// mid-save leaves the previous file as it was.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "hxmap/mapfile/map_file.hpp"
#include "test_data.hpp"

namespace hxmap::drv {
namespace {

namespace fs = std::filesystem;

/// A map whose every voxel holds random bits (finite floats): a round trip
/// that drops or reorders any field shows.
alg::TsdfMap randomMap(int side, uint32_t seed) {
  alg::TsdfParams p;
  p.voxel_size_m = 0.02;
  p.truncation_m = 0.08;
  alg::TsdfMap map(p);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (int x = -side; x < side; ++x) {
    for (int y = -side; y < side; ++y) {
      for (int z = 0; z < 3; ++z) {
        alg::VoxelBlock& b = map.block(static_cast<size_t>(map.findOrAllocate({x, y, z})));
        for (int v = 0; v < alg::kBlockVoxels; ++v) {
          if (rng() % 4 == 0) continue;  // some voxels never observed
          b.geo[v] = {0.08f * u(rng), 64.0f * std::abs(u(rng))};
          b.color[v] = {static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng()),
                        static_cast<uint8_t>(rng() % 2)};
          b.stats[v] = {static_cast<uint32_t>(rng() % 1000), u(rng), std::abs(u(rng))};
        }
        b.seen_through = rng() % 3 == 0;
      }
    }
  }
  return map;
}

alg::KeyframeDatabase randomKeyframes(int count, uint32_t seed) {
  alg::KeyframeDatabase db;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < count; ++i) {
    alg::FrameFeatures f;
    const int n = 50 + i;
    f.descriptors = cv::Mat(n, 32, CV_8U);
    for (int r = 0; r < n; ++r) {
      for (int c = 0; c < 32; ++c) f.descriptors.at<uint8_t>(r, c) = static_cast<uint8_t>(rng());
      f.points_cam.emplace_back(static_cast<float>(u(rng)), static_cast<float>(u(rng)),
                                1.0f + static_cast<float>(std::abs(u(rng))));
      f.pixels.emplace_back(0.0f, 0.0f);
    }
    const Eigen::Isometry3d T = Eigen::Translation3d(u(rng), u(rng), u(rng)) *
                                Eigen::AngleAxisd(u(rng), Eigen::Vector3d(u(rng), u(rng), 1.0).normalized());
    db.add(static_cast<uint32_t>(10 * i + 3), f, T);
  }
  return db;
}

void expectSameMap(const alg::TsdfMap& a, const alg::TsdfMap& b) {
  ASSERT_EQ(a.blockCount(), b.blockCount());
  EXPECT_EQ(a.voxelSize(), b.voxelSize());
  EXPECT_EQ(a.truncation(), b.truncation());
  for (size_t i = 0; i < a.blockCount(); ++i) {
    const int32_t j = b.find(a.key(i));
    ASSERT_GE(j, 0) << "block " << a.key(i).transpose();
    const alg::VoxelBlock& x = a.block(i);
    const alg::VoxelBlock& y = b.block(static_cast<size_t>(j));
    EXPECT_EQ(std::memcmp(x.geo, y.geo, sizeof x.geo), 0);
    EXPECT_EQ(std::memcmp(x.color, y.color, sizeof x.color), 0);
    EXPECT_EQ(std::memcmp(x.stats, y.stats, sizeof x.stats), 0);
    EXPECT_EQ(x.seen_through, y.seen_through);
  }
}

std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}
void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

TEST(MapFile, ARoundTripIsBitExactPerBlockAndKeepsTheKeyframes) {
  const std::string dir = test::tempDir("mapfile_roundtrip");
  const alg::TsdfMap map = randomMap(6, 1);
  const alg::KeyframeDatabase db = randomKeyframes(7, 2);
  const auto saved = saveMap(dir + "/m.hxm", map, &db);
  ASSERT_TRUE(saved) << saved.message();
  EXPECT_EQ(saved->blocks, 432u);
  EXPECT_EQ(saved->keyframes, 7u);
  EXPECT_EQ(saved->bytes, fs::file_size(dir + "/m.hxm"));
  const auto loaded = loadMap(dir + "/m.hxm");
  ASSERT_TRUE(loaded) << loaded.message();
  expectSameMap(map, loaded->map);
  EXPECT_EQ(loaded->info.version, kMapFileVersion);
  EXPECT_EQ(loaded->info.frames, kMapFileFrames);
  EXPECT_EQ(loaded->skipped_blocks, 0u);
  ASSERT_EQ(loaded->keyframes.size(), db.size());
  for (size_t i = 0; i < db.size(); ++i) {
    const auto& a = db.keyframes()[i];
    const auto& b = loaded->keyframes.keyframes()[i];
    EXPECT_EQ(a.id, b.id);
    EXPECT_TRUE(a.T_world_cam.matrix() == b.T_world_cam.matrix()) << "keyframe " << a.id;
    ASSERT_EQ(a.descriptors.rows, b.descriptors.rows);
    EXPECT_EQ(cv::norm(a.descriptors, b.descriptors, cv::NORM_L1), 0.0);
    EXPECT_EQ(a.points_cam, b.points_cam);
  }
  // The header alone.
  const auto info = readMapInfo(dir + "/m.hxm");
  ASSERT_TRUE(info) << info.message();
  EXPECT_EQ(info->blocks, 432u);
  EXPECT_EQ(info->keyframes, 7u);
  EXPECT_DOUBLE_EQ(info->tsdf.voxel_size_m, 0.02);
  EXPECT_GT(info->block_bytes, 0u);
  EXPECT_LT(info->block_bytes, info->file_bytes);
}

TEST(MapFile, AnEmptyMapRoundTrips) {
  const std::string dir = test::tempDir("mapfile_empty");
  alg::TsdfParams p;
  p.voxel_size_m = 0.01;
  p.truncation_m = 0.04;
  const alg::TsdfMap map(p);
  ASSERT_TRUE(saveMap(dir + "/e.hxm", map));
  const auto loaded = loadMap(dir + "/e.hxm");
  ASSERT_TRUE(loaded) << loaded.message();
  EXPECT_EQ(loaded->map.blockCount(), 0u);
  EXPECT_FLOAT_EQ(loaded->map.voxelSize(), 0.01f);
}

TEST(MapFile, ATruncatedFileIsAnErrorNamingTheFileAndWhereItEnds) {
  const std::string dir = test::tempDir("mapfile_truncated");
  ASSERT_TRUE(saveMap(dir + "/m.hxm", randomMap(3, 3)));
  const std::string bytes = readBytes(dir + "/m.hxm");
  for (size_t cut : {size_t{0}, size_t{10}, size_t{100}, bytes.size() / 2, bytes.size() - 1}) {
    writeBytes(dir + "/cut.hxm", bytes.substr(0, cut));
    const auto loaded = loadMap(dir + "/cut.hxm");
    ASSERT_FALSE(loaded) << "cut at " << cut;
    EXPECT_NE(loaded.message().find(dir + "/cut.hxm"), std::string::npos) << loaded.message();
    if (cut >= 16) {
      EXPECT_NE(loaded.message().find("truncated"), std::string::npos) << loaded.message();
    }
  }
  const auto missing = loadMap(dir + "/nope.hxm");
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.message().find("nope.hxm: cannot open"), std::string::npos) << missing.message();
}

TEST(MapFile, ACorruptBlockIsAnErrorWithItsOffsetOrSkippedWhenAsked) {
  const std::string dir = test::tempDir("mapfile_corrupt");
  const alg::TsdfMap map = randomMap(3, 4);
  ASSERT_TRUE(saveMap(dir + "/m.hxm", map));
  std::string bytes = readBytes(dir + "/m.hxm");
  // A byte inside the third block's compressed voxels: the header (132
  // bytes) and two records come first; records are at least 28 bytes.
  const size_t at = bytes.size() / 3;
  bytes[at] = static_cast<char>(bytes[at] ^ 0x5a);
  writeBytes(dir + "/bad.hxm", bytes);
  const auto loaded = loadMap(dir + "/bad.hxm");
  ASSERT_FALSE(loaded);
  EXPECT_NE(loaded.message().find("bad.hxm"), std::string::npos) << loaded.message();
  EXPECT_NE(loaded.message().find("offset"), std::string::npos) << loaded.message();
  EXPECT_NE(loaded.message().find("--skip-bad"), std::string::npos) << loaded.message();

  MapLoadOptions skip;
  skip.skip_bad = true;
  const auto skipped = loadMap(dir + "/bad.hxm", skip);
  ASSERT_TRUE(skipped) << skipped.message();
  EXPECT_EQ(skipped->skipped_blocks, 1u);
  EXPECT_EQ(skipped->map.blockCount(), map.blockCount() - 1);
  // Every block that is left is the saved one.
  size_t same = 0;
  for (size_t i = 0; i < skipped->map.blockCount(); ++i) {
    const int32_t j = map.find(skipped->map.key(i));
    ASSERT_GE(j, 0);
    same += std::memcmp(map.block(static_cast<size_t>(j)).geo, skipped->map.block(i).geo,
                        sizeof(alg::VoxelBlock::geo)) == 0;
  }
  EXPECT_EQ(same, skipped->map.blockCount());
}

TEST(MapFile, AnotherVersionOrVoxelSizeOrFormatIsAClearError) {
  const std::string dir = test::tempDir("mapfile_version");
  ASSERT_TRUE(saveMap(dir + "/m.hxm", randomMap(2, 5)));
  std::string bytes = readBytes(dir + "/m.hxm");
  std::string v2 = bytes;
  const uint32_t two = 2;
  std::memcpy(v2.data() + 8, &two, 4);
  writeBytes(dir + "/v2.hxm", v2);
  const auto a = loadMap(dir + "/v2.hxm");
  ASSERT_FALSE(a);
  EXPECT_NE(a.message().find("v2.hxm: map file format version 2, this build reads version 1"), std::string::npos)
      << a.message();

  MapLoadOptions fine;
  fine.tsdf = alg::TsdfParams{};
  fine.tsdf->voxel_size_m = 0.01;
  fine.tsdf->truncation_m = 0.04;
  const auto b = loadMap(dir + "/m.hxm", fine);
  ASSERT_FALSE(b);
  EXPECT_NE(b.message().find("0.02 m voxels"), std::string::npos) << b.message();
  EXPECT_NE(b.message().find("0.01 m"), std::string::npos) << b.message();
  EXPECT_NE(b.message().find("tsdf.voxel_size_m"), std::string::npos) << b.message();

  writeBytes(dir + "/text.hxm", "ply\nformat ascii 1.0\n");
  const auto c = loadMap(dir + "/text.hxm");
  ASSERT_FALSE(c);
  EXPECT_NE(c.message().find("text.hxm: not an hxmap map file"), std::string::npos) << c.message();

  std::string header = bytes;
  header[30] = static_cast<char>(header[30] ^ 1);  // inside the voxel size
  writeBytes(dir + "/header.hxm", header);
  const auto d = loadMap(dir + "/header.hxm");
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("header checksum"), std::string::npos) << d.message();
}

TEST(MapFile, AWriterKilledMidSaveLeavesThePreviousFileIntact) {
  const std::string dir = test::tempDir("mapfile_kill");
  const std::string path = dir + "/m.hxm";
  const alg::TsdfMap before = randomMap(3, 6);
  ASSERT_TRUE(saveMap(path, before));
  const std::string before_bytes = readBytes(path);
  const alg::TsdfMap big = randomMap(24, 7);  // 6912 blocks: a save takes long enough to be caught
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    for (;;) (void)saveMap(path, big);
  }
  // Wait for the child's temporary file, then kill it mid-write.
  const std::string tmp = path + ".tmp." + std::to_string(child);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (!(fs::exists(tmp) && fs::file_size(tmp) > 0) && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::microseconds(200));
  }
  ::kill(child, SIGKILL);
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status));
  // Unless the child got a whole save in (then the big map is there, whole).
  const auto loaded = loadMap(path);
  ASSERT_TRUE(loaded) << loaded.message();
  if (readBytes(path) == before_bytes) {
    expectSameMap(before, loaded->map);
  } else {
    expectSameMap(big, loaded->map);
  }
  if (fs::exists(tmp) && fs::file_size(tmp) < readBytes(path).size()) {
    EXPECT_FALSE(loadMap(tmp)) << "the temporary file was cut short";
  }
}

}  // namespace
}  // namespace hxmap::drv
