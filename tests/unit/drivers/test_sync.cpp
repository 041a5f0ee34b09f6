// Stream pairing on synthetic streams with jitter, drops and stalls, and
// depth-to-color registration with a known geometry.
#include <gtest/gtest.h>

#include <random>
#include <set>

#include "hxmap/sync/sync.hpp"

namespace hxmap::drv {
namespace {

constexpr int64_t kMs = 1'000'000;

ColorImage color(int64_t t, uint64_t seq) { return {t, seq, cv::Mat(2, 2, CV_8UC3, cv::Scalar(0))}; }
DepthImage depth(int64_t t, uint64_t seq) { return {t, seq, cv::Mat(2, 2, CV_16UC1, cv::Scalar(0))}; }

std::vector<SyncedPair> drain(StreamSync& sync) {
  std::vector<SyncedPair> out;
  while (auto p = sync.pop()) out.push_back(std::move(*p));
  return out;
}

// Two 30 Hz streams, each frame with +-4 ms jitter, each stream dropping 10%
// of its frames; arrivals interleaved with up to 2 frames of lag.
TEST(StreamSync, PairsEachColorFrameWithItsOwnDepthDespiteJitterAndDrops) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int64_t> jitter(-4 * kMs, 4 * kMs);
  std::bernoulli_distribution drop(0.1);
  const int n = 600;
  std::vector<int64_t> tc(n), td(n);
  std::vector<bool> has_c(n), has_d(n);
  for (int i = 0; i < n; ++i) {
    tc[i] = i * 33 * kMs + jitter(rng);
    td[i] = i * 33 * kMs + 5 * kMs + jitter(rng);  // depth ~5 ms later
    has_c[i] = !drop(rng);
    has_d[i] = !drop(rng);
  }
  StreamSync sync(0.02, 8);
  std::vector<SyncedPair> pairs;
  for (int i = 0; i < n + 2; ++i) {
    if (i < n && has_c[i]) sync.pushColor(color(tc[i], i));
    if (i >= 2 && has_d[i - 2]) sync.pushDepth(depth(td[i - 2], i - 2));  // depth lags two frames
    for (auto& p : drain(sync)) pairs.push_back(std::move(p));
  }
  size_t expected = 0;
  for (int i = 0; i < n; ++i) expected += has_c[i] && has_d[i];
  ASSERT_EQ(pairs.size(), expected);
  std::set<uint64_t> used_depth;
  int64_t last = INT64_MIN;
  for (const auto& p : pairs) {
    EXPECT_EQ(p.color.seq, p.depth.seq) << "color " << p.color.seq << " paired with depth " << p.depth.seq;
    EXPECT_LE(std::llabs(p.color.stamp_ns - p.depth.stamp_ns), 20 * kMs);
    EXPECT_GT(p.color.stamp_ns, last);
    last = p.color.stamp_ns;
    EXPECT_TRUE(used_depth.insert(p.depth.seq).second);
  }
  const SyncStats& s = sync.stats();
  EXPECT_EQ(s.pairs, expected);
  size_t colors = 0, depths = 0;
  for (int i = 0; i < n; ++i) {
    colors += has_c[i];
    depths += has_d[i];
  }
  // Every frame is paired, dropped (counted) or still queued.
  EXPECT_EQ(s.pairs + s.color_dropped + sync.queuedColor(), colors);
  EXPECT_EQ(s.pairs + s.depth_dropped + sync.queuedDepth(), depths);
  EXPECT_LE(s.max_gap_paired_s, 0.02);
}

TEST(StreamSync, SlowerDepthStreamPairsWithTheNearestColorFrames) {
  StreamSync sync(0.010, 8);
  std::vector<SyncedPair> pairs;
  for (int i = 0; i < 60; ++i) {
    sync.pushColor(color(i * 33 * kMs, i));
    if (i % 2 == 0) sync.pushDepth(depth(i * 33 * kMs + 2 * kMs, i));  // 15 Hz
    for (auto& p : drain(sync)) pairs.push_back(std::move(p));
  }
  sync.pushColor(color(60 * 33 * kMs, 60));
  sync.pushDepth(depth(60 * 33 * kMs + 2 * kMs, 60));
  for (auto& p : drain(sync)) pairs.push_back(std::move(p));
  ASSERT_EQ(pairs.size(), 31u);
  for (const auto& p : pairs) EXPECT_EQ(p.color.seq, p.depth.seq);
  EXPECT_EQ(sync.stats().color_dropped, 30u);  // the odd color frames: nearest depth is 31 ms away
}

TEST(StreamSync, StalledDepthStreamKeepsTheColorQueueBounded) {
  StreamSync sync(0.02, 5);
  for (int i = 0; i < 100; ++i) {
    sync.pushColor(color(i * 33 * kMs, i));
    EXPECT_FALSE(sync.pop());
    EXPECT_LE(sync.queuedColor(), 5u);
  }
  EXPECT_EQ(sync.stats().color_dropped, 95u);
  // The depth stream comes back: pairing resumes with the frames still queued.
  sync.pushDepth(depth(99 * 33 * kMs + kMs, 0));
  auto pairs = drain(sync);
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_EQ(pairs[0].color.seq, 99u);
}

TEST(StreamSync, OutOfOrderStampsAreDroppedAndCounted) {
  StreamSync sync(0.02);
  sync.pushColor(color(100 * kMs, 0));
  sync.pushColor(color(90 * kMs, 1));   // backwards
  sync.pushColor(color(100 * kMs, 2));  // repeated
  sync.pushDepth(depth(101 * kMs, 0));
  sync.pushDepth(depth(50 * kMs, 1));
  EXPECT_EQ(sync.stats().out_of_order, 3u);
  auto pairs = drain(sync);
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_EQ(pairs[0].color.seq, 0u);
}

TEST(Registration, IdentityRigKeepsDepthAndAShiftMovesAPlaneExactly) {
  const alg::PinholeCamera cam{300, 300, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};
  cv::Mat d(240, 320, CV_32F, cv::Scalar(2.0f));
  d(cv::Rect(0, 0, 10, 240)) = 0.0f;  // no measurement
  const cv::Mat same = registerDepth(d, cam, cam, Eigen::Isometry3d::Identity());
  EXPECT_EQ(cv::norm(same, d, cv::NORM_INF), 0.0);

  // A fronto-parallel plane at 2 m seen by a depth camera 4 cm to the color
  // camera's right: in the color camera it is still at 2 m, shifted by
  // f * b / z = 6 px; all pixels away from the borders are covered.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0.04, 0, 0);
  cv::Mat plane(240, 320, CV_32F, cv::Scalar(2.0f));
  const cv::Mat reg = registerDepth(plane, cam, cam, T);
  int covered = 0;
  for (int v = 0; v < 240; ++v) {
    for (int u = 20; u < 300; ++u) {
      const float z = reg.at<float>(v, u);
      if (z > 0) {
        EXPECT_NEAR(z, 2.0f, 1e-5f);
        ++covered;
      }
    }
  }
  EXPECT_EQ(covered, 240 * 280);
  EXPECT_EQ(reg.at<float>(120, 5), 0.0f);  // no depth pixel lands left of 6 px

  // Occlusion: a near square in front of the plane wins where both land.
  cv::Mat two = plane.clone();
  two(cv::Rect(150, 110, 20, 20)) = 0.5f;
  const cv::Mat occl = registerDepth(two, cam, cam, T);
  // The square's center moves by 300 * 0.04 / 0.5 = 24 px.
  EXPECT_NEAR(occl.at<float>(120, 160 + 24), 0.5f, 1e-5f);
  EXPECT_NEAR(occl.at<float>(120, 100), 2.0f, 1e-5f);
}

TEST(FrameAssembler, ConvertsRegistersAndRejectsWrongFrames) {
  RigCalibration cal;
  cal.color = {300, 300, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};
  cal.depth = cal.color;
  cal.depth_scale = 5000;
  cal.max_depth_m = 4.0;
  auto a = FrameAssembler::create(cal);
  ASSERT_TRUE(a) << a.message();
  ColorImage c{10, 3, cv::Mat(240, 320, CV_8UC3, cv::Scalar(1, 2, 3))};
  DepthImage d{12, 4, cv::Mat(240, 320, CV_16UC1, cv::Scalar(5000))};
  d.raw.at<uint16_t>(0, 0) = 0;
  d.raw.at<uint16_t>(0, 1) = 30000;  // 6 m: beyond max_depth_m
  auto f = a->assemble(c, d, 7);
  ASSERT_TRUE(f) << f.message();
  EXPECT_EQ(f->stamp_ns, 10);
  EXPECT_EQ(f->seq, 7u);
  EXPECT_FLOAT_EQ(f->depth.at<float>(5, 5), 1.0f);
  EXPECT_EQ(f->depth.at<float>(0, 0), 0.0f);
  EXPECT_EQ(f->depth.at<float>(0, 1), 0.0f);
  EXPECT_EQ(f->rgb.at<cv::Vec3b>(5, 5), cv::Vec3b(1, 2, 3));

  DepthImage small{12, 5, cv::Mat(120, 160, CV_16UC1, cv::Scalar(5000))};
  auto bad = a->assemble(c, small, 8);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.message().find("depth frame 5: 160x120"), std::string::npos) << bad.message();
  ColorImage gray{10, 6, cv::Mat(240, 320, CV_8UC1)};
  auto bad2 = a->assemble(gray, d, 9);
  ASSERT_FALSE(bad2);
  EXPECT_NE(bad2.message().find("color frame 6"), std::string::npos) << bad2.message();

  RigCalibration wrong = cal;
  wrong.depth_scale = 0;
  auto e = FrameAssembler::create(wrong);
  ASSERT_FALSE(e);
  EXPECT_NE(e.message().find("depth_scale"), std::string::npos);
  wrong = cal;
  wrong.depth.fx = -1;
  auto e2 = FrameAssembler::create(wrong);
  ASSERT_FALSE(e2);
  EXPECT_NE(e2.message().find("depth camera"), std::string::npos) << e2.message();
}

}  // namespace
}  // namespace hxmap::drv
