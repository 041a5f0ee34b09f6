// V4L2: pixel format conversions on captured buffers, and the streaming
// state machine against a scripted stand-in device (no camera on the build
// machines): format negotiation, driver drops, corrupt and truncated
// buffers, a camera unplugged and plugged back, one that never returns, and
// the real system calls on a missing device and a non-V4L2 node.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <linux/videodev2.h>

#include <cerrno>
#include <cstring>
#include <deque>
#include <set>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "hxmap/v4l2/camera.hpp"
#include "hxmap/v4l2/convert.hpp"
#include "scripted_v4l2.hpp"

namespace hxmap::drv {
namespace {

using test::ScriptedDevice;
using test::testImage;

double meanAbsDiff(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat d;
  cv::absdiff(a, b, d);
  const cv::Scalar m = cv::mean(d);
  return (m[0] + m[1] + m[2]) / 3;
}

TEST(V4l2Convert, YuyvRoundTripsWithinChromaSubsamplingError) {
  const cv::Mat rgb = testImage(64, 48);
  const std::vector<uint8_t> yuyv = encodeYuyv(rgb);
  ASSERT_EQ(yuyv.size(), 64u * 48 * 2);
  auto out = decodeColor(PixelFormat::kYuyv, yuyv.data(), yuyv.size(), 64, 48);
  ASSERT_TRUE(out) << out.message();
  EXPECT_LT(meanAbsDiff(*out, rgb), 3.0);
  // Known values: black, white and pure red in limited range.
  const uint8_t black[4] = {16, 128, 16, 128}, white[4] = {235, 128, 235, 128}, red[4] = {81, 90, 81, 240};
  EXPECT_EQ((*decodeColor(PixelFormat::kYuyv, black, 4, 2, 1)).at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));
  EXPECT_EQ((*decodeColor(PixelFormat::kYuyv, white, 4, 2, 1)).at<cv::Vec3b>(0, 1), cv::Vec3b(255, 255, 255));
  const cv::Vec3b r = (*decodeColor(PixelFormat::kYuyv, red, 4, 2, 1)).at<cv::Vec3b>(0, 0);
  EXPECT_GE(r[0], 250);
  EXPECT_LE(r[1], 3);
  EXPECT_LE(r[2], 3);
}

TEST(V4l2Convert, RowStrideIsHonoured) {
  const cv::Mat rgb = testImage(30, 10);
  std::vector<uint8_t> padded(40 * 3 * 10, 0xAB);
  for (int v = 0; v < 10; ++v) std::memcpy(&padded[static_cast<size_t>(v) * 120], rgb.ptr(v), 90);
  auto out = decodeColor(PixelFormat::kRgb24, padded.data(), padded.size(), 30, 10, 120);
  ASSERT_TRUE(out) << out.message();
  EXPECT_EQ(cv::norm(*out, rgb, cv::NORM_INF), 0.0);
}

TEST(V4l2Convert, MjpegDecodesAndCorruptOrTruncatedFramesAreErrors) {
  const cv::Mat rgb = testImage(64, 48);
  cv::Mat bgr;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  std::vector<uint8_t> jpg;
  cv::imencode(".jpg", bgr, jpg, {cv::IMWRITE_JPEG_QUALITY, 95});
  auto out = decodeColor(PixelFormat::kMjpeg, jpg.data(), jpg.size(), 64, 48);
  ASSERT_TRUE(out) << out.message();
  EXPECT_LT(meanAbsDiff(*out, rgb), 3.0);
  auto truncated = decodeColor(PixelFormat::kMjpeg, jpg.data(), jpg.size() / 2, 64, 48);
  ASSERT_FALSE(truncated);
  EXPECT_NE(truncated.message().find("truncated"), std::string::npos) << truncated.message();
  std::vector<uint8_t> garbage(jpg.size(), 0x5A);
  EXPECT_FALSE(decodeColor(PixelFormat::kMjpeg, garbage.data(), garbage.size(), 64, 48));
  auto wrong_size = decodeColor(PixelFormat::kMjpeg, jpg.data(), jpg.size(), 320, 240);
  ASSERT_FALSE(wrong_size);
  EXPECT_NE(wrong_size.message().find("decoded 64x48"), std::string::npos) << wrong_size.message();
}

TEST(V4l2Convert, MjpegFramesGoToTheJpegDecoderOnly) {
  const cv::Mat rgb = testImage(64, 48);
  cv::Mat bgr;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  std::vector<uint8_t> jpg;
  cv::imencode(".jpg", bgr, jpg, {cv::IMWRITE_JPEG_QUALITY, 95});
  // Junk inside the compressed scan: a damaged picture is a dropped frame.
  std::vector<uint8_t> damaged = jpg;
  const size_t middle = damaged.size() * 2 / 3;
  const uint8_t junk[6] = {0xFF, 0xD0, 0x13, 0x37, 0xFF, 0xD3};
  std::copy(junk, junk + 6, damaged.begin() + static_cast<long>(middle));
  auto d = decodeColor(PixelFormat::kMjpeg, damaged.data(), damaged.size(), 64, 48);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("has corrupt JPEG data"), std::string::npos) << d.message();
  // Extraneous bytes before EOI (many UVC cameras send them) leave every
  // pixel intact: the frame is kept.
  std::vector<uint8_t> padded(jpg.begin(), jpg.end() - 2);
  padded.insert(padded.end(), {0x00, 0x00, 0x00, 0xFF, 0xD9});
  auto p = decodeColor(PixelFormat::kMjpeg, padded.data(), padded.size(), 64, 48);
  ASSERT_TRUE(p) << p.message();
  EXPECT_LT(meanAbsDiff(*p, rgb), 3.0);
  // Found by fuzzing: SOI without a JPEG's third byte and "DICM" at offset
  // 128 was handed by OpenCV's imdecode to its DICOM decoder, which crashed.
  // Found by fuzzing: SOI not followed by a marker, and "DICM" further on;
  // OpenCV's imdecode handed it to its DICOM decoder, which crashed.
  const std::vector<uint8_t> fake = {
      0xFF, 0xD8, 0x38, 0x0A, 0x0A, 0x06, 0x08, 0x0B, 0x0C, 0x0B, 0x0A, 0x0C, 0x09, 0x0A, 0x0A, 0x0A, 0xFF, 0xDB,
      0x00, 0x43, 0x01, 0x02, 0x02, 0x02, 0x02, 0x02, 0x02, 0x05, 0x03, 0x03, 0x05, 0x0A, 0x07, 0x06, 0x07, 0x0A,
      0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A,
      0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A,
      0x1A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0x0A, 0xFF, 0xC0, 0x00, 0x11, 0x08,
      0x00, 0x0C, 0x00, 0x10, 0x03, 0x32, 0x22, 0x00, 0x02, 0x11, 0x01, 0x03, 0x11, 0x01, 0x95, 0x7D, 0x22, 0x00,
      0x40, 0x60, 0x00, 0x00, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
      0x01, 0x02, 0x44, 0x49, 0x43, 0x4D, 0x07, 0x08, 0x09, 0x0A, 0x3F, 0x3F, 0xF7, 0x3F, 0xFF, 0xD9,
  };
  auto f = decodeColor(PixelFormat::kMjpeg, fake.data(), fake.size(), 16, 11);
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("is corrupt"), std::string::npos) << f.message();
}

TEST(V4l2Convert, Z16IsLittleEndianAndShortBuffersAreErrors) {
  const uint8_t z[8] = {0x88, 0x13, 0x00, 0x00, 0xff, 0xff, 0x01, 0x00};
  auto d = decodeDepth(z, 8, 2, 2);
  ASSERT_TRUE(d) << d.message();
  EXPECT_EQ(d->at<uint16_t>(0, 0), 5000);
  EXPECT_EQ(d->at<uint16_t>(0, 1), 0);
  EXPECT_EQ(d->at<uint16_t>(1, 0), 65535);
  EXPECT_EQ(d->at<uint16_t>(1, 1), 1);
  auto shortbuf = decodeDepth(z, 7, 2, 2);
  ASSERT_FALSE(shortbuf);
  EXPECT_NE(shortbuf.message().find("holds 7 bytes"), std::string::npos) << shortbuf.message();
  EXPECT_FALSE(decodeColor(PixelFormat::kYuyv, z, 8, 3, 1));  // odd width
  EXPECT_EQ(formatOfFourcc(V4L2_PIX_FMT_Z16), PixelFormat::kZ16);
  EXPECT_EQ(fourccText(V4L2_PIX_FMT_YUYV), "YUYV");
}

/// Options for the scripted device at its own size.
V4l2Options scriptedOptions() {
  V4l2Options o;
  o.device = "/dev/video-scripted";
  o.width = 64;
  o.height = 48;
  return o;
}

TEST(V4l2Camera, StreamsDecodesAndCountsDriverDropsAndCorruptFrames) {
  auto dev = std::make_shared<ScriptedDevice>();
  dev->drop_at = {3, 4};
  dev->truncate_at = {6};
  V4l2Options o = scriptedOptions();
  o.formats = {PixelFormat::kMjpeg, PixelFormat::kYuyv};  // MJPEG refused: YUYV negotiated
  auto cam = V4l2Camera::open(o, dev);
  ASSERT_TRUE(cam) << cam.message();
  EXPECT_EQ((*cam)->format(), PixelFormat::kYuyv);
  EXPECT_EQ((*cam)->card(), "scripted UVC camera");
  std::vector<V4l2Frame> frames;
  for (int i = 0; i < 8; ++i) {
    auto f = (*cam)->grab(1.0);
    ASSERT_TRUE(f) << f.message();
    frames.push_back(std::move(*f));
  }
  // Driver sequence 0 1 2 (3 4 dropped) 5 6 7 [8 truncated] 9 10 ...
  const std::vector<uint64_t> want_seq = {0, 1, 2, 5, 6, 7, 9, 10};
  for (size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(frames[i].sequence, want_seq[i]);
    EXPECT_EQ(frames[i].stamp_ns, 1'000'000'000 + static_cast<int64_t>(want_seq[i]) * 33'333'333 / 1000 * 1000);
    ASSERT_EQ(frames[i].image.type(), CV_8UC3);
    EXPECT_LT(meanAbsDiff(frames[i].image, testImage(64, 48, static_cast<int>(want_seq[i]))), 3.0);
  }
  EXPECT_EQ((*cam)->stats().lost_by_driver, 2u);
  EXPECT_EQ((*cam)->stats().corrupt, 1u);
  EXPECT_EQ((*cam)->stats().frames, 8u);
}

TEST(V4l2Camera, ReconnectsWhenTheCameraComesBackAndCountsTheGap) {
  auto dev = std::make_shared<ScriptedDevice>();
  dev->unplug_at = 3;
  dev->opens_before_return = 2;
  V4l2Options o = scriptedOptions();
  o.reconnect_timeout_s = 5;
  auto cam = V4l2Camera::open(o, dev);
  ASSERT_TRUE(cam) << cam.message();
  std::vector<uint64_t> seqs;
  for (int i = 0; i < 6; ++i) {
    auto f = (*cam)->grab(2.0);
    ASSERT_TRUE(f) << f.message();
    seqs.push_back(f->sequence);
  }
  EXPECT_EQ((*cam)->stats().reconnects, 1u);
  EXPECT_EQ(dev->open_calls, 4);  // first open, two failures, success
  EXPECT_GT((*cam)->stats().disconnected_s, 0.15);  // two 100 ms waits
  // Sequence numbers keep increasing across the reconnect, with the gap.
  for (size_t i = 1; i < seqs.size(); ++i) EXPECT_GT(seqs[i], seqs[i - 1]);
  EXPECT_EQ(seqs[3] - seqs[2] - 1, (*cam)->stats().lost_while_disconnected);
  EXPECT_EQ(dev->mapped, 4);  // the old mappings were released, the new ones made
}

TEST(V4l2Camera, ACameraThatNeverReturnsIsAClearError) {
  auto dev = std::make_shared<ScriptedDevice>();
  dev->unplug_at = 1;
  V4l2Options o = scriptedOptions();
  o.reconnect_timeout_s = 0.3;
  auto cam = V4l2Camera::open(o, dev);
  ASSERT_TRUE(cam) << cam.message();
  ASSERT_TRUE((*cam)->grab(1.0));
  auto f = (*cam)->grab(1.0);
  ASSERT_FALSE(f);
  EXPECT_NE(f.message().find("/dev/video-scripted: the camera disappeared and did not come back"), std::string::npos)
      << f.message();
  EXPECT_EQ(dev->mapped, 0);
}

TEST(V4l2Camera, NoWantedFormatIsAClearError) {
  auto dev = std::make_shared<ScriptedDevice>();
  dev->formats = {V4L2_PIX_FMT_Z16};
  V4l2Options o;
  o.device = "/dev/video-scripted";
  auto cam = V4l2Camera::open(o, dev);
  ASSERT_FALSE(cam);
  EXPECT_NE(cam.message().find("none of the wanted formats"), std::string::npos) << cam.message();
  EXPECT_NE(cam.message().find("offered Z16"), std::string::npos) << cam.message();
  // As a depth camera it streams.
  o.formats = {PixelFormat::kZ16};
  o.width = 64;
  o.height = 48;
  auto depth = V4l2Camera::open(o, dev);
  ASSERT_TRUE(depth) << depth.message();
  auto f = (*depth)->grab(1.0);
  ASSERT_TRUE(f) << f.message();
  ASSERT_EQ(f->image.type(), CV_16UC1);
  EXPECT_EQ(f->image.at<uint16_t>(10, 10), 0x1300);
}

TEST(V4l2Camera, MissingDeviceAndNonV4l2NodeAreClearErrors) {
  V4l2Options o;
  o.device = "/dev/video-hxmap-missing";
  auto missing = V4l2Camera::open(o);
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.message().find("/dev/video-hxmap-missing: cannot open the camera"), std::string::npos)
      << missing.message();
  o.device = "/dev/null";
  auto null_dev = V4l2Camera::open(o);
  ASSERT_FALSE(null_dev);
  EXPECT_NE(null_dev.message().find("/dev/null: not a V4L2 device"), std::string::npos) << null_dev.message();
}

}  // namespace
}  // namespace hxmap::drv
