// The run's output folder: a finished run is never lost, two runs never
// mix, an interrupted run's poses are kept.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "run_folder.hpp"
#include "test_data.hpp"

namespace hxmap::rt {
namespace {
namespace fs = std::filesystem;

std::string readAll(const fs::path& p) {
  std::ifstream in(p);
  return {std::istreambuf_iterator<char>(in), {}};
}

void writeFile(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << text;
}

/// A fresh --out path (not created) with no leftovers beside it.
std::string freshOut(const std::string& name) {
  const std::string base = test::tempDir(name);
  for (const auto& e : fs::directory_iterator(fs::path(base).parent_path())) {
    if (e.path().filename().string().rfind(fs::path(base).filename().string() + ".", 0) == 0) fs::remove_all(e.path());
  }
  return base + "/out";
}

TEST(RunFolder, TimeInTheOutPathIsTheUtcStart) {
  EXPECT_EQ(expandOutPath("runs/{time}", 0), "runs/19700101-000000");
  EXPECT_EQ(expandOutPath("r-{time}-{time}", 86400 + 3661), "r-19700102-010101-19700102-010101");
  EXPECT_EQ(expandOutPath("plain", 5), "plain");
}

TEST(RunFolder, AFinishedRunIsReplacedOnlyWhenAskedAndAsAWhole) {
  const std::string out = freshOut("replace");
  {
    auto f = RunFolder::open(out, false);
    ASSERT_TRUE(f) << f.message();
    EXPECT_FALSE(fs::exists(out)) << "nothing is written into --out before the commit";
    writeFile(f->path("summary.txt"), "first\n");
    writeFile(f->path("mesh.ply"), "mesh one\n");
    writeFile(f->path("q/kf0000.png"), "quality\n");
    ASSERT_TRUE(f->commit());
  }
  EXPECT_EQ(readAll(out + "/summary.txt"), "first\n");
  EXPECT_FALSE(fs::exists(out + ".partial"));
  writeFile(out + "/notes.txt", "the user's own\n");  // not a run's output: kept

  auto refused = RunFolder::open(out, false);
  ASSERT_FALSE(refused);
  EXPECT_NE(refused.message().find(out + " holds a finished run"), std::string::npos) << refused.message();
  EXPECT_NE(refused.message().find("--overwrite"), std::string::npos) << refused.message();
  EXPECT_EQ(readAll(out + "/summary.txt"), "first\n");

  {
    auto f = RunFolder::open(out, true);
    ASSERT_TRUE(f) << f.message();
    writeFile(f->path("summary.txt"), "second\n");
    // Until the commit, --out is the first run, whole.
    EXPECT_EQ(readAll(out + "/summary.txt"), "first\n");
    EXPECT_EQ(readAll(out + "/mesh.ply"), "mesh one\n");
    ASSERT_TRUE(f->commit());
  }
  EXPECT_EQ(readAll(out + "/summary.txt"), "second\n");
  EXPECT_FALSE(fs::exists(out + "/mesh.ply")) << "the first run's mesh is not left beside the second's summary";
  EXPECT_FALSE(fs::exists(out + "/q")) << "nor its quality images";
  EXPECT_EQ(readAll(out + "/notes.txt"), "the user's own\n");
  EXPECT_FALSE(fs::exists(out + ".partial"));
}

TEST(RunFolder, AnUncommittedRunLeavesTheFolderAsItWas) {
  const std::string out = freshOut("discard");
  writeFile(out + "/summary.txt", "finished\n");
  {
    auto f = RunFolder::open(out, true);
    ASSERT_TRUE(f) << f.message();
    writeFile(f->path("summary.txt"), "failed\n");
    f->discard();
  }
  {
    auto f = RunFolder::open(out, true);
    ASSERT_TRUE(f) << f.message();
    writeFile(f->path("summary.txt"), "also failed\n");
  }  // destroyed without commit (an error return)
  EXPECT_EQ(readAll(out + "/summary.txt"), "finished\n");
  EXPECT_FALSE(fs::exists(out + ".partial"));
}

TEST(RunFolder, TwoRunsCannotWriteTheSameFolder) {
  const std::string out = freshOut("two");
  auto first = RunFolder::open(out, false);
  ASSERT_TRUE(first) << first.message();
  auto second = RunFolder::open(out, false);
  ASSERT_FALSE(second);
  EXPECT_NE(second.message().find("being written by another hxmap run"), std::string::npos) << second.message();
  EXPECT_TRUE(fs::exists(first->staging())) << "the second run did not touch the first one's folder";
}

TEST(RunFolder, AKilledRunsPosesAreKeptAside) {
  const std::string out = freshOut("killed");
  // What a run killed with SIGKILL leaves: its staging folder with the
  // poses appended so far (the lock died with the process).
  writeFile(out + ".partial/trajectory_live.txt", "# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n");
  auto f = RunFolder::open(out, false);
  ASSERT_TRUE(f) << f.message();
  EXPECT_NE(f->notice().find("was interrupted"), std::string::npos) << f->notice();
  int kept = 0;
  for (const auto& e : fs::directory_iterator(fs::path(out).parent_path())) {
    const std::string name = e.path().filename().string();
    if (name.rfind("out.interrupted-", 0) == 0) {
      ++kept;
      EXPECT_EQ(readAll(e.path() / "trajectory_live.txt"), "# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n");
    }
  }
  EXPECT_EQ(kept, 1);
}

TEST(RunFolder, PathsInsideTheOutputGoWithTheSet) {
  const std::string out = freshOut("redirect");
  auto f = RunFolder::open(out, false);
  ASSERT_TRUE(f) << f.message();
  EXPECT_EQ(f->redirect(out + "/q"), f->staging() + "/q");
  EXPECT_EQ(f->redirect(out + "/sub/../trace.json"), f->staging() + "/trace.json");
  EXPECT_EQ(f->redirect("/elsewhere/trace.json"), "/elsewhere/trace.json");
  EXPECT_EQ(f->redirect(""), "");
  EXPECT_TRUE(isUnder(out + "/a/b", out));
  EXPECT_FALSE(isUnder(out + "-other/a", out));
}

TEST(RunFolder, ABadOutPathIsAnErrorNamingIt) {
  const std::string base = test::tempDir("bad");
  writeFile(base + "/file", "x");
  auto not_a_folder = RunFolder::open(base + "/file", true);
  ASSERT_FALSE(not_a_folder);
  EXPECT_NE(not_a_folder.message().find(base + "/file: exists and is not a folder"), std::string::npos)
      << not_a_folder.message();
  auto root = RunFolder::open("/", true);
  ASSERT_FALSE(root);
  EXPECT_NE(root.message().find("--out '/'"), std::string::npos) << root.message();
}

TEST(LiveTrajectoryFile, EveryPoseIsOnDiskAsSoonAsItIsAppended) {
  const std::string dir = test::tempDir("live");
  auto file = LiveTrajectoryFile::open(dir + "/t.txt");
  ASSERT_TRUE(file) << file.message();
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  T_world_cam.translation() << 1, 2, 3;
  file->append(1'500'000'000, T_world_cam);
  // Read while the file is still open: nothing waits in a buffer.
  EXPECT_EQ(readAll(dir + "/t.txt"),
            "# timestamp tx ty tz qx qy qz qw\n1.500000 1.000000 2.000000 3.000000 0.000000 0.000000 0.000000 "
            "1.000000\n");
  auto bad = LiveTrajectoryFile::open(dir + "/no/such/folder/t.txt");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.message().find(dir + "/no/such/folder/t.txt"), std::string::npos) << bad.message();
}

}  // namespace
}  // namespace hxmap::rt
