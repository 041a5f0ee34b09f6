#include <filesystem>

#include <gtest/gtest.h>

#include "hxmap/config/config.hpp"

namespace hxmap::rt {
namespace {

TEST(Config, EmptyGivesDefaults) {
  auto c = loadConfigFromString("", "empty.yaml");
  ASSERT_TRUE(c) << c.message();
  EXPECT_DOUBLE_EQ(c->tsdf.voxel_size_m, alg::TsdfParams{}.voxel_size_m);
}

TEST(Config, ReadsValues) {
  auto c = loadConfigFromString("tsdf:\n  voxel_size_m: 0.01\n  truncation_m: 0.04\ndataset:\n  skip_bad_frames: true\n",
                                "a.yaml");
  ASSERT_TRUE(c) << c.message();
  EXPECT_DOUBLE_EQ(c->tsdf.voxel_size_m, 0.01);
  EXPECT_TRUE(c->dataset.skip_bad_frames);
}

TEST(Config, ReportsEveryProblemAtOnceWithLines) {
  const std::string yaml =
      "tsdf:\n"
      "  voxel_size_m: abc\n"       // line 2: type
      "  voxel_sz: 0.01\n"          // line 3: unknown key
      "tracking:\n"
      "  max_normal_angle_deg: 200\n"  // line 5: range
      "trackng:\n"                  // line 6: unknown section
      "  x: 1\n"
      "dataset:\n"
      "  initial_pose: magic\n";    // line 9: choice
  auto c = loadConfigFromString(yaml, "bad.yaml");
  ASSERT_FALSE(c);
  const std::string& m = c.message();
  EXPECT_NE(m.find("5 problem(s)"), std::string::npos) << m;
  EXPECT_NE(m.find("bad.yaml:2: tsdf.voxel_size_m: expected a number, got 'abc'"), std::string::npos) << m;
  EXPECT_NE(m.find("bad.yaml:3: unknown key 'tsdf.voxel_sz'"), std::string::npos) << m;
  EXPECT_NE(m.find("bad.yaml:5: tracking.max_normal_angle_deg: 200 is outside the allowed range [1, 90]"),
            std::string::npos) << m;
  EXPECT_NE(m.find("bad.yaml:6: unknown section 'trackng'"), std::string::npos) << m;
  EXPECT_NE(m.find("bad.yaml:9: dataset.initial_pose: 'magic' is not one of: ground_truth, identity"),
            std::string::npos) << m;
}

TEST(Config, SyntaxErrorNamesLine) {
  auto c = loadConfigFromString("tsdf:\n  voxel_size_m: [0.01\n", "s.yaml");
  ASSERT_FALSE(c);
  EXPECT_NE(c.message().find("s.yaml:"), std::string::npos) << c.message();
  EXPECT_NE(c.message().find("YAML syntax error"), std::string::npos) << c.message();
}

TEST(Config, RelationsBetweenKeys) {
  auto c = loadConfigFromString("tsdf:\n  voxel_size_m: 0.05\n  truncation_m: 0.06\n", "r.yaml");
  ASSERT_FALSE(c);
  EXPECT_NE(c.message().find("truncation_m must be at least 2 * tsdf.voxel_size_m"), std::string::npos);
}

TEST(Config, MissingFileIsNamed) {
  auto c = loadConfig("/nonexistent/hxmap.yaml");
  ASSERT_FALSE(c);
  EXPECT_NE(c.message().find("/nonexistent/hxmap.yaml"), std::string::npos);
}

TEST(Config, AFolderAndDuplicateKeysAreErrorsNotSilentDefaults) {
  auto dir = loadConfig(::testing::TempDir());
  ASSERT_FALSE(dir);
  EXPECT_NE(dir.message().find("is a folder, not a configuration file"), std::string::npos) << dir.message();
  // YAML would keep the first of each and drop the rest without a word.
  auto dup = loadConfigFromString(
      "tsdf:\n  voxel_size_m: 0.02\n  voxel_size_m: 0.01\ncamera:\n  fx: 500\ntsdf:\n  truncation_m: 0.08\n",
      "dup.yaml");
  ASSERT_FALSE(dup);
  EXPECT_NE(dup.message().find("dup.yaml:3: key 'tsdf.voxel_size_m' appears twice"), std::string::npos)
      << dup.message();
  EXPECT_NE(dup.message().find("dup.yaml:6: section 'tsdf' appears twice"), std::string::npos) << dup.message();
}

TEST(Config, ListsOrMappingsAsNamesAreErrorsNamingTheLine) {
  // YAML allows any node as a key; a configuration's names are words. (Found
  // by fuzzing: reading such a key as text threw out of the loader.)
  auto section = loadConfigFromString("camera:\n  fx: 500\n[tsdf, x]: 1\n", "k.yaml");
  ASSERT_FALSE(section);
  EXPECT_NE(section.message().find("k.yaml:3: a section's name must be a word, not a list"), std::string::npos)
      << section.message();
  auto key = loadConfigFromString("tsdf:\n  ? {voxel_size_m: 1}\n  : 0.02\n", "k.yaml");
  ASSERT_FALSE(key);
  EXPECT_NE(key.message().find("k.yaml:2: a key in tsdf must be a word, not a mapping"), std::string::npos)
      << key.message();
}

TEST(Config, EveryPresetLoadsAndDefaultMatchesTheStructs) {
  const std::filesystem::path dir = std::filesystem::path(HXMAP_SOURCE_DIR) / "config";
  int presets = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.path().extension() != ".yaml") continue;
    auto c = loadConfig(e.path().string());
    EXPECT_TRUE(c) << c.message();
    ++presets;
  }
  EXPECT_GE(presets, 6);
  auto d = loadConfig((dir / "default.yaml").string());
  ASSERT_TRUE(d) << d.message();
  EXPECT_EQ(dumpConfig(*d), dumpConfig(HxmapConfig{})) << "config/default.yaml is out of date with the structs";
}

}  // namespace
}  // namespace hxmap::rt
