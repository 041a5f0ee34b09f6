// Values read from the real data slices in ../shared/data.
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "hxmap/dataset/dataset.hpp"
#include "test_data.hpp"

namespace hxmap::drv {
namespace {

constexpr const char* kTum = "tum/rgbd_dataset_freiburg1_xyz_first40";
constexpr const char* kReplica = "replica/room0_first20/room0";
constexpr const char* kTumFull = "tum/rgbd_dataset_freiburg1_xyz";

TEST(RealData, JpegsDecodeToTheSamePixelsAsOpenCvs) {
  // Color JPEGs go through libjpeg directly (so corrupt data is caught);
  // the pixels must be OpenCV's, bit for bit: the whole fr1/xyz recording
  // (re-encoded as JPEG) and Replica's frames.
  for (const std::string& rel : {std::string(kTumFull) + "/rgb", std::string(kReplica) + "/results"}) {
    HXMAP_REQUIRE_SHARED_DATA(rel);
    int compared = 0;
    for (const auto& e : std::filesystem::directory_iterator(test::sharedData(rel))) {
      if (compared == 8) break;
      auto bytes = readTextFile(e.path().string());
      ASSERT_TRUE(bytes) << bytes.message();
      if (bytes->size() < 2 || static_cast<uint8_t>((*bytes)[0]) != 0xFF || static_cast<uint8_t>((*bytes)[1]) != 0xD8) {
        continue;  // not a JPEG (depth PNGs beside the color)
      }
      auto ours = decodeImage(*bytes, e.path().string(), "rgb.txt", false);
      ASSERT_TRUE(ours) << ours.message();
      cv::Mat bgr = cv::imread(e.path().string(), cv::IMREAD_COLOR), rgb;
      cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
      ASSERT_EQ(ours->size(), rgb.size());
      ASSERT_EQ(ours->type(), rgb.type());
      EXPECT_EQ(cv::norm(*ours, rgb, cv::NORM_INF), 0.0) << e.path();
      ++compared;
    }
    EXPECT_EQ(compared, 8) << rel << " holds JPEG color images";
  }
}

TEST(RealTum, AssociationIntrinsicsAndGroundTruth) {
  HXMAP_REQUIRE_SHARED_DATA(kTum);
  auto d = Dataset::open(test::sharedData(kTum));
  ASSERT_TRUE(d) << d.message();
  const Dataset& ds = **d;
  // 40 color and 41 depth images; associate.py semantics (<= 0.02 s, greedy
  // closest first) pair 35 of them.
  EXPECT_EQ(ds.size(), 35u);
  EXPECT_EQ(ds.stamp(0), 1305031102175304000LL);
  EXPECT_EQ(ds.stamp(34), 1305031103475274000LL);
  EXPECT_DOUBLE_EQ(ds.camera().fx, 517.3);
  EXPECT_DOUBLE_EQ(ds.camera().fy, 516.5);
  EXPECT_DOUBLE_EQ(ds.camera().cx, 318.6);
  EXPECT_DOUBLE_EQ(ds.camera().cy, 255.3);
  EXPECT_FALSE(ds.camera().hasDistortion()) << "frames are undistorted by the reader";
  EXPECT_DOUBLE_EQ(ds.depthScale(), 5000.0);
  // groundtruth.txt line "1305031102.1758 1.3405 0.6266 1.6575 0.6574 0.6126 -0.2949 -0.3248".
  const auto& gt = ds.groundTruth();
  ASSERT_EQ(gt.size(), 3000u);  // the untrimmed motion-capture file
  auto it = std::find_if(gt.begin(), gt.end(), [](const StampedPose& p) { return p.stamp_ns == 1305031102175800000LL; });
  ASSERT_NE(it, gt.end());
  EXPECT_NEAR(it->T_world_cam.translation().x(), 1.3405, 1e-9);
  EXPECT_NEAR(it->T_world_cam.translation().z(), 1.6575, 1e-9);
  const Eigen::Quaterniond q(it->T_world_cam.linear());
  const Eigen::Quaterniond expected = Eigen::Quaterniond(-0.3248, 0.6574, 0.6126, -0.2949).normalized();
  EXPECT_NEAR(std::abs(q.dot(expected)), 1.0, 1e-9);

  auto f = ds.load(0);
  ASSERT_TRUE(f) << f.message();
  EXPECT_EQ(f->rgb.size(), cv::Size(640, 480));
  EXPECT_EQ(f->depth.type(), CV_32FC1);
  // Kinect depth of the desk scene: valid pixels between 0.4 and 5 m, mostly valid.
  int valid = 0;
  double max_z = 0;
  for (int v = 0; v < 480; ++v) {
    for (int u = 0; u < 640; ++u) {
      const float z = f->depth.at<float>(v, u);
      if (z > 0) {
        ++valid;
        max_z = std::max(max_z, static_cast<double>(z));
        EXPECT_GT(z, 0.3f);
      }
    }
  }
  EXPECT_GT(valid, 640 * 480 / 2);
  EXPECT_LT(max_z, 6.0);
}

TEST(RealReplica, FramesIntrinsicsAndPose) {
  HXMAP_REQUIRE_SHARED_DATA(kReplica);
  auto d = Dataset::open(test::sharedData(kReplica));
  ASSERT_TRUE(d) << d.message();
  const Dataset& ds = **d;
  EXPECT_EQ(ds.kind(), DatasetKind::kReplica);
  EXPECT_EQ(ds.size(), 20u);
  EXPECT_EQ(ds.camera().width, 1200);
  EXPECT_EQ(ds.camera().height, 680);
  EXPECT_DOUBLE_EQ(ds.camera().fx, 600.0);
  EXPECT_DOUBLE_EQ(ds.camera().cx, 599.5);
  EXPECT_DOUBLE_EQ(ds.depthScale(), 6553.5);
  ASSERT_EQ(ds.groundTruth().size(), 20u);
  // traj.txt row 1: translation 3.4530, 0.4546, 0.5936.
  const Eigen::Vector3d t = ds.groundTruth()[0].T_world_cam.translation();
  EXPECT_NEAR(t.x(), 3.452987416406734678, 1e-9);
  EXPECT_NEAR(t.y(), 0.4546110134135947223, 1e-9);
  EXPECT_NEAR(t.z(), 0.5936285447159415085, 1e-9);
  auto f = ds.load(0);
  ASSERT_TRUE(f) << f.message();
  EXPECT_EQ(f->rgb.size(), cv::Size(1200, 680));
}

}  // namespace
}  // namespace hxmap::drv
