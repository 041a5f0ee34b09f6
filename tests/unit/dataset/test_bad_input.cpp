// Every kind of bad dataset input gives an error that names the file (and the
// list line), or with skip_bad a counted skip.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "test_data.hpp"

namespace fs = std::filesystem;

namespace hxmap::drv {
namespace {

void writeFile(const fs::path& p, const std::string& content) {
  std::ofstream(p, std::ios::binary) << content;
}
std::string readFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::tempDir("tum");
    SyntheticParams p;
    p.frames = 3;
    p.camera = alg::PinholeCamera{60, 60, 31.5, 23.5, 64, 48, {0, 0, 0, 0, 0}};
    ASSERT_TRUE(writeSyntheticSequence(dir_, SyntheticScene::room(), p));
    rgb0_ = fs::path(dir_) / firstListed("rgb.txt");
    depth0_ = fs::path(dir_) / firstListed("depth.txt");
  }
  std::string firstListed(const std::string& list) {
    std::ifstream in(fs::path(dir_) / list);
    std::string line;
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#') return line.substr(line.find(' ') + 1);
    }
    return {};
  }
  Expected<RgbdFrame> loadFirst(const DatasetOptions& o = {}) {
    auto d = Dataset::open(dir_, o);
    if (!d) return Error{d.message()};
    return (*d)->load(0);
  }
  std::string dir_;
  fs::path rgb0_, depth0_;
};

TEST_F(BadInput, EveryBadCalibrationValueIsReportedTogetherWithItsKey) {
  const fs::path calib = fs::path(dir_) / "calibration.yaml";
  // Sizes far beyond any sensor (once an uncaught OpenCV exception when
  // the undistortion maps were built), a NaN and an infinite focal length,
  // a principal point outside the image, a zero depth scale, a non-finite
  // distortion and an unknown key: one error naming each.
  writeFile(calib,
            "fx: .nan\nfy: .inf\ncx: -3\ncy: 10\nwidth: 200000\nheight: 200000\ndepth_scale: 0\n"
            "distortion: [0.1, .nan, 0, 0, 0]\nfocal: 525\n");
  auto d = Dataset::open(dir_, {});
  ASSERT_FALSE(d);
  const std::string& m = d.message();
  EXPECT_NE(m.find("8 problem(s)"), std::string::npos) << m;
  for (const char* key : {":1: fx", ":2: fy", ":3: cx", ":5: width", ":6: height", ":7: depth_scale",
                          ":8: distortion", ":9: 'focal'"}) {
    EXPECT_NE(m.find(calib.string() + key), std::string::npos) << key << " in\n" << m;
  }
  // A missing key and a value that is not a number.
  writeFile(calib, "fx: 60\nfy: sixty\ncx: 31.5\nwidth: 64\nheight: 48\n");
  d = Dataset::open(dir_, {});
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find(calib.string() + ":2: fy must be a number"), std::string::npos) << d.message();
  EXPECT_NE(d.message().find("missing key 'cy'"), std::string::npos) << d.message();
  // Within bounds, it opens with the values given.
  writeFile(calib, "fx: 60\nfy: 61\ncx: 31.5\ncy: 23.5\nwidth: 64\nheight: 48\ndepth_scale: 1000\n");
  d = Dataset::open(dir_, {});
  ASSERT_TRUE(d) << d.message();
  EXPECT_DOUBLE_EQ((*d)->camera().fy, 61.0);
  EXPECT_DOUBLE_EQ((*d)->depthScale(), 1000.0);
}

TEST_F(BadInput, ATumFolderWithoutIntrinsicsIsAnErrorThatSaysWhatToAdd) {
  // A TUM-layout folder without calibration.yaml, whose name names no
  // freiburg preset (a renamed copy of a recording): no silent default.
  fs::remove(fs::path(dir_) / "calibration.yaml");
  auto d = Dataset::open(dir_, {});
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find(dir_), std::string::npos) << d.message();
  EXPECT_NE(d.message().find("calibration.yaml"), std::string::npos) << d.message();
  EXPECT_NE(d.message().find("--camera-preset"), std::string::npos) << d.message();
  // A named preset (as `--camera-preset kinect` passes it) opens it.
  DatasetOptions o;
  o.camera = cameraPreset("kinect");
  o.camera_origin = "--camera-preset kinect";
  o.force_camera = true;
  auto with_preset = Dataset::open(dir_, o);
  ASSERT_TRUE(with_preset) << with_preset.message();
  EXPECT_DOUBLE_EQ((*with_preset)->camera().fx, 525.0);
  EXPECT_EQ((*with_preset)->cameraSource(), "--camera-preset kinect");
  EXPECT_DOUBLE_EQ(cameraPreset("fr1").fx, 517.3);
}

TEST_F(BadInput, TheUntouchedSequenceLoads) {
  auto f = loadFirst();
  ASSERT_TRUE(f) << f.message();
  EXPECT_EQ(f->depth.type(), CV_32FC1);
  EXPECT_EQ(f->rgb.size(), cv::Size(64, 48));
}

TEST_F(BadInput, MissingListFile) {
  fs::remove(fs::path(dir_) / "depth.txt");
  auto d = Dataset::open(dir_);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("depth.txt: file does not exist"), std::string::npos) << d.message();
}

TEST_F(BadInput, EmptyListFile) {
  writeFile(fs::path(dir_) / "rgb.txt", "# color images\n");
  auto d = Dataset::open(dir_);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("rgb.txt: the list has no entries"), std::string::npos) << d.message();
}

TEST_F(BadInput, ListedFileMissing) {
  fs::remove(rgb0_);
  auto f = loadFirst();
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("rgb.txt:3: listed file"), std::string::npos) << f.message();
  EXPECT_NE(f.message().find("does not exist"), std::string::npos) << f.message();
}

TEST_F(BadInput, CorruptPng) {
  writeFile(rgb0_, std::string("\x89PNG\r\n\x1a\n", 8) + std::string(200, 'x') + "IEND\xae\x42\x60\x82");
  auto f = loadFirst();
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("is corrupt"), std::string::npos) << f.message();
  EXPECT_NE(f.message().find(rgb0_.filename().string()), std::string::npos) << f.message();
}

TEST_F(BadInput, TruncatedPng) {
  const std::string bytes = readFile(depth0_);
  writeFile(depth0_, bytes.substr(0, bytes.size() / 2));
  auto f = loadFirst();
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("depth.txt:3:"), std::string::npos) << f.message();
  EXPECT_NE(f.message().find("truncated PNG"), std::string::npos) << f.message();
}

TEST_F(BadInput, NotAnImage) {
  writeFile(rgb0_, "hello");
  auto f = loadFirst();
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("is not a PNG or JPEG image"), std::string::npos) << f.message();
}

TEST_F(BadInput, WrongBitDepth) {
  cv::imwrite(depth0_.string(), cv::Mat(48, 64, CV_8UC1, cv::Scalar(10)));
  auto f = loadFirst();
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("is 8-bit 1-channel, expected 16-bit single-channel"), std::string::npos)
      << f.message();
}

TEST_F(BadInput, WrongSize) {
  cv::imwrite(depth0_.string(), cv::Mat(24, 32, CV_16UC1, cv::Scalar(1000)));
  auto f = loadFirst();
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("is 32x24 but the camera is 64x48"), std::string::npos) << f.message();
}

TEST_F(BadInput, NanPose) {
  writeFile(fs::path(dir_) / "groundtruth.txt", "# gt\n1.0 0 0 0 0 0 0 1\n1.1 0 nan 0 0 0 0 1\n");
  auto d = Dataset::open(dir_);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("groundtruth.txt:3: a value is not a finite number"), std::string::npos) << d.message();
}

TEST_F(BadInput, SkipModeCountsBadLines) {
  const std::string list = readFile(fs::path(dir_) / "rgb.txt");
  writeFile(fs::path(dir_) / "rgb.txt", list + "garbage line here\n");
  DatasetOptions o;
  o.skip_bad = true;
  auto d = Dataset::open(dir_, o);
  ASSERT_TRUE(d) << d.message();
  EXPECT_EQ((*d)->size(), 3u);
  ASSERT_EQ((*d)->skippedAtOpen().size(), 1u);
  EXPECT_NE((*d)->skippedAtOpen()[0].find("rgb.txt:6"), std::string::npos) << (*d)->skippedAtOpen()[0];
}

TEST_F(BadInput, NotADatasetFolder) {
  auto d = Dataset::open(dir_ + "/rgb");
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("not a dataset folder"), std::string::npos) << d.message();
  auto missing = Dataset::open(dir_ + "/nope");
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.message().find("dataset folder does not exist"), std::string::npos);
}

// Replica layout: JPEG color, non-rigid trajectory rows, missing depth.
class BadReplica : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::tempDir("replica");
    fs::create_directories(fs::path(dir_) / "results");
    for (int i = 0; i < 2; ++i) {
      char name[64];
      std::snprintf(name, sizeof(name), "results/frame%06d.jpg", i);
      cv::imwrite((fs::path(dir_) / name).string(), cv::Mat(48, 64, CV_8UC3, cv::Scalar(10, 20, 30)));
      std::snprintf(name, sizeof(name), "results/depth%06d.png", i);
      cv::imwrite((fs::path(dir_) / name).string(), cv::Mat(48, 64, CV_16UC1, cv::Scalar(6553)));
    }
    writeFile(fs::path(dir_) / "traj.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0.1 0 1 0 0 0 0 1 0 0 0 0 1\n");
    writeFile(fs::path(dir_) / "cam_params.json",
              R"({"camera": {"w": 64, "h": 48, "fx": 60.0, "fy": 60.0, "cx": 31.5, "cy": 23.5, "scale": 6553.5}})");
  }
  std::string dir_;
};

TEST_F(BadReplica, LoadsWhenIntact) {
  auto d = Dataset::open(dir_);
  ASSERT_TRUE(d) << d.message();
  EXPECT_EQ((*d)->kind(), DatasetKind::kReplica);
  auto f = (*d)->load(1);
  ASSERT_TRUE(f) << f.message();
  EXPECT_NEAR(f->depth.at<float>(0, 0), 6553.0 / 6553.5, 1e-6);
  EXPECT_NEAR((*d)->groundTruth()[1].T_world_cam.translation().x(), 0.1, 1e-12);
}

TEST_F(BadReplica, TruncatedJpeg) {
  const fs::path jpg = fs::path(dir_) / "results/frame000001.jpg";
  const std::string bytes = readFile(jpg);
  writeFile(jpg, bytes.substr(0, bytes.size() - 40));
  auto d = Dataset::open(dir_);
  ASSERT_TRUE(d) << d.message();
  auto f = (*d)->load(1);
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("frame000001.jpg is a truncated JPEG"), std::string::npos) << f.message();
}

TEST_F(BadReplica, GarbageInsideTheJpegDataIsAnError) {
  // The file is whole (SOI ... EOI) but its compressed data is not: the
  // decoder would hand out a damaged picture; it is an error naming it.
  const fs::path jpg = fs::path(dir_) / "results/frame000001.jpg";
  std::string bytes = readFile(jpg);
  const size_t sos = bytes.find("\xFF\xDA");
  ASSERT_NE(sos, std::string::npos);
  const size_t middle = sos + (bytes.size() - sos) / 2;
  bytes.replace(middle, 6, "\xFF\xD0\x13\x37\xFF\xD3");  // stray restart markers and junk in the scan
  writeFile(jpg, bytes);
  auto d = Dataset::open(dir_);
  ASSERT_TRUE(d) << d.message();
  auto f = (*d)->load(1);
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("frame000001.jpg has corrupt JPEG data"), std::string::npos) << f.message();
  auto intact = (*d)->load(0);
  ASSERT_TRUE(intact) << intact.message();
}

TEST_F(BadReplica, NonRigidPose) {
  writeFile(fs::path(dir_) / "traj.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0.5 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n");
  auto d = Dataset::open(dir_);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("traj.txt:2: the matrix is not a rigid transform"), std::string::npos) << d.message();
}

TEST_F(BadReplica, MissingDepthAndShortTrajectory) {
  fs::remove(fs::path(dir_) / "results/depth000001.png");
  auto d = Dataset::open(dir_);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("depth image for frame 1 is missing"), std::string::npos) << d.message();
  DatasetOptions o;
  o.skip_bad = true;
  auto skipped = Dataset::open(dir_, o);
  ASSERT_TRUE(skipped) << skipped.message();
  EXPECT_EQ((*skipped)->size(), 1u);
  EXPECT_EQ((*skipped)->skippedAtOpen().size(), 1u);
}

TEST_F(BadReplica, EveryBadCameraParameterIsReportedWithItsKey) {
  // Sizes OpenCV would choke on, a negative focal length, a principal
  // point outside the image, a zero depth scale: one error naming all.
  const fs::path params = fs::path(dir_) / "cam_params.json";
  writeFile(params,
            "{\"camera\": {\"w\": 200000, \"h\": 48, \"fx\": -60.0, \"fy\": 60.0, \"cx\": 31.5,\n"
            "  \"cy\": 99.0, \"scale\": 0}}");
  auto d = Dataset::open(dir_);
  ASSERT_FALSE(d);
  const std::string& m = d.message();
  EXPECT_NE(m.find("4 problem(s) in the camera parameters"), std::string::npos) << m;
  EXPECT_NE(m.find(params.string() + ":1: camera.fx must be a positive focal length"), std::string::npos) << m;
  EXPECT_NE(m.find(params.string() + ":1: camera.w must be a whole number of pixels in [1, 8192]"), std::string::npos)
      << m;
  EXPECT_NE(m.find(params.string() + ":2: camera.cy must lie inside the image, [0, 48)"), std::string::npos) << m;
  EXPECT_NE(m.find(params.string() + ":2: camera.scale must be positive"), std::string::npos) << m;
  writeFile(params, R"({"camera": {"w": 64, "h": 48, "fx": 60.0, "fy": 60.0, "cx": 31.5}})");
  auto missing = Dataset::open(dir_);
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.message().find(params.string() + ": missing key 'camera.cy'"), std::string::npos)
      << missing.message();
  writeFile(params, "[1, 2");
  auto broken = Dataset::open(dir_);
  ASSERT_FALSE(broken);
  EXPECT_EQ(broken.message().rfind(params.string() + ": ", 0), 0u) << broken.message();
}

}  // namespace
}  // namespace hxmap::drv
