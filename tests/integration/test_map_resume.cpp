// Saving a map and continuing it: a run cut in two relocalizes in the map
// the first half saved and maps on in its frame; a map of another scene is
// not relocalized in, and the run fails or starts a new map as configured.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>

#include "commands.hpp"
#include "hxmap/dataset/parsers.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/mapfile/map_file.hpp"
#include "test_data.hpp"

namespace hxmap::rt {
namespace {

const char* kSlice = "tum/rgbd_dataset_freiburg1_xyz_first40";

std::string readText(const std::string& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), {}};
}

std::string writeConfig(const std::string& dir, const std::string& name, const std::string& yaml) {
  const std::string path = dir + "/" + name;
  std::ofstream(path) << yaml;
  return path;
}

Trajectory readTrajectory(const std::string& path) {
  auto t = drv::parseTumTrajectory(readText(path), path);
  return t ? t->poses : Trajectory{};
}

TEST(MapResume, ARunCutInTwoRelocalizesInTheSavedMapAndMapsOnInItsFrame) {
  HXMAP_REQUIRE_SHARED_DATA(kSlice);
  const std::string data = test::sharedData(kSlice), dir = test::tempDir("cut");
  RunOptions first;
  first.dataset = data;
  first.out_dir = dir + "/first";
  first.config = writeConfig(dir, "first.yaml", "dataset: {max_frames: 20}\n");
  first.save_map = dir + "/map.hxm";
  ASSERT_EQ(runCommand(first), 0);
  const auto info = drv::readMapInfo(first.save_map);
  ASSERT_TRUE(info) << info.message();
  EXPECT_GT(info->blocks, 100u);
  EXPECT_GE(info->keyframes, 2u);

  RunOptions second;
  second.dataset = data;
  second.out_dir = dir + "/second";
  second.config = writeConfig(dir, "second.yaml", "dataset: {first_frame: 20}\n");
  second.load_map = first.save_map;
  second.save_map = dir + "/map2.hxm";
  ASSERT_EQ(runCommand(second), 0);
  const std::string summary = readText(second.out_dir + "/summary.txt");
  const size_t at = summary.find("relocalized in it at frame ");
  ASSERT_NE(at, std::string::npos) << summary;
  EXPECT_LE(std::stoi(summary.substr(at + 27)), 2) << summary;
  // Its poses are in the saved map's frame (the first run's, taken from the
  // ground truth): unaligned, within 4 cm of the truth (the first run's own
  // drift included; a new map would start at the identity, 2 m away).
  const Trajectory est = readTrajectory(second.out_dir + "/trajectory.txt");
  auto truth = drv::parseTumTrajectory(readText(data + "/groundtruth.txt"), data + "/groundtruth.txt");
  ASSERT_TRUE(truth);
  ASSERT_EQ(est.size(), 15u);  // the slice has 35 frames
  double worst = 0;
  for (const StampedPose& p : est) {
    Eigen::Isometry3d T;
    ASSERT_TRUE(alg::interpolatePose(truth->poses, p.stamp_ns, 200'000'000, T));
    worst = std::max(worst, (T.translation() - p.T_world_cam.translation()).norm());
  }
  EXPECT_LT(worst, 0.04) << "largest distance to the ground truth, unaligned (m)";
  // The continued map holds the first one and grew.
  const auto grown = drv::readMapInfo(second.save_map);
  ASSERT_TRUE(grown) << grown.message();
  EXPECT_GE(grown->blocks, info->blocks);
  EXPECT_GT(grown->keyframes, info->keyframes);
}

TEST(MapResume, AMapOfAnotherSceneFailsTheRunOrMakesWayForANewMapAsConfigured) {
  HXMAP_REQUIRE_SHARED_DATA(kSlice);
  const std::string data = test::sharedData(kSlice), dir = test::tempDir("other");
  // A map of the synthetic room.
  drv::SyntheticParams sp;
  sp.frames = 15;
  ASSERT_TRUE(drv::writeSyntheticSequence(dir + "/room", drv::SyntheticScene::room(), sp));
  RunOptions room;
  room.dataset = dir + "/room";
  room.out_dir = dir + "/room_out";
  room.no_mesh_eval = true;
  room.save_map = dir + "/room.hxm";
  // Refinement is not what this is about (offline, each keyframe's jobs run
  // to their end: most of this test's time under the sanitizers).
  room.config = writeConfig(dir, "room.yaml", "refine: {enabled: false}\n");
  ASSERT_EQ(runCommand(room), 0);

  RunOptions o;
  o.dataset = data;
  o.load_map = room.save_map;
  o.out_dir = dir + "/fail";
  o.config = writeConfig(dir, "fail.yaml", "runtime: {resume_relocalize_frames: 5}\nrefine: {enabled: false}\n");
  EXPECT_EQ(runCommand(o), 1);
  EXPECT_FALSE(std::filesystem::exists(o.out_dir + "/summary.txt")) << "nothing was mapped: --out is left as it was";

  o.out_dir = dir + "/new";
  o.config = writeConfig(dir, "new.yaml", "runtime: {resume_relocalize_frames: 5, resume_otherwise: new_map}\nrefine: {enabled: false}\n");
  ASSERT_EQ(runCommand(o), 0);
  const std::string summary = readText(o.out_dir + "/summary.txt");
  EXPECT_NE(summary.find("set aside, a new map was started"), std::string::npos) << summary;
  EXPECT_NE(summary.find("lost 5 "), std::string::npos) << summary;

  // A map of another voxel size is a usage error naming both.
  o.out_dir = dir + "/fine";
  o.config = writeConfig(dir, "fine.yaml", "tsdf: {voxel_size_m: 0.01, truncation_m: 0.04}\n");
  EXPECT_EQ(runCommand(o), 2);
}

}  // namespace
}  // namespace hxmap::rt
