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

namespace hxmap::drv {
namespace {

cv::Mat testImage(int w, int h, int k = 0) {
  cv::Mat rgb(h, w, CV_8UC3);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(static_cast<uint8_t>((u * 3 + k) & 255), static_cast<uint8_t>((v * 3) & 255),
                                          static_cast<uint8_t>(((u + v) * 2) & 255));
    }
  }
  cv::GaussianBlur(rgb, rgb, cv::Size(5, 5), 1.5);  // smooth: chroma subsampling keeps it
  return rgb;
}

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

// A camera that is not there: a YUYV (and Z16) UVC device in memory whose
// script says when it drops, corrupts, unplugs and comes back.
class ScriptedDevice : public DeviceIo {
 public:
  std::set<uint32_t> formats{V4L2_PIX_FMT_YUYV};
  int width = 64, height = 48;
  bool present = true;
  int opens_before_return = -1;    ///< after an unplug: failed opens before it is back (-1 = never)
  uint64_t unplug_at = UINT64_MAX; ///< DQBUF number at which it disappears
  std::set<uint64_t> drop_at;      ///< driver sequence numbers skipped
  std::set<uint64_t> truncate_at;  ///< DQBUF numbers delivered short
  uint64_t dequeues = 0;
  int open_calls = 0, mapped = 0;

  int open(const char*, int) override {
    ++open_calls;
    if (!present) {
      if (opens_before_return == 0) {
        present = true;
        sequence_ = 0;
      } else {
        if (opens_before_return > 0) --opens_before_return;
        errno = ENOENT;
        return -1;
      }
    }
    return 7;
  }
  int close(int) override { return 0; }
  int ioctl(int, unsigned long request, void* arg) override {
    if (!present && request != VIDIOC_STREAMOFF) return fail(ENODEV);
    switch (request) {
      case VIDIOC_QUERYCAP: {
        auto* c = static_cast<v4l2_capability*>(arg);
        std::strcpy(reinterpret_cast<char*>(c->card), "scripted UVC camera");
        c->capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        return 0;
      }
      case VIDIOC_S_FMT: {
        auto* f = static_cast<v4l2_format*>(arg);
        if (!formats.count(f->fmt.pix.pixelformat)) f->fmt.pix.pixelformat = *formats.begin();
        f->fmt.pix.width = static_cast<uint32_t>(width);
        f->fmt.pix.height = static_cast<uint32_t>(height);
        f->fmt.pix.bytesperline = static_cast<uint32_t>(width * 2);
        format_ = f->fmt.pix.pixelformat;
        return 0;
      }
      case VIDIOC_S_PARM: return 0;
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        buffers_.assign(r->count, std::vector<uint8_t>(static_cast<size_t>(width * height * 2)));
        queue_.clear();
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->length = static_cast<uint32_t>(buffers_[b->index].size());
        b->m.offset = b->index * 65536;
        return 0;
      }
      case VIDIOC_QBUF: queue_.push_back(static_cast<v4l2_buffer*>(arg)->index); return 0;
      case VIDIOC_STREAMON: return 0;
      case VIDIOC_STREAMOFF: return present ? 0 : fail(ENODEV);
      case VIDIOC_DQBUF: {
        if (dequeues == unplug_at) {
          present = false;
          ++dequeues;
          return fail(ENODEV);
        }
        if (queue_.empty()) return fail(EAGAIN);
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->index = queue_.front();
        queue_.pop_front();
        while (drop_at.count(sequence_)) ++sequence_;
        b->sequence = static_cast<uint32_t>(sequence_);
        const int64_t t = 1'000'000'000 + static_cast<int64_t>(sequence_) * 33'333'333;
        b->timestamp.tv_sec = t / 1'000'000'000;
        b->timestamp.tv_usec = (t % 1'000'000'000) / 1000;
        b->flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
        std::vector<uint8_t>& buf = buffers_[b->index];
        if (format_ == V4L2_PIX_FMT_Z16) {
          for (size_t i = 0; i < buf.size(); i += 2) {
            buf[i] = static_cast<uint8_t>(sequence_ & 0xff);
            buf[i + 1] = 0x13;
          }
        } else {
          const std::vector<uint8_t> yuyv = encodeYuyv(testImage(width, height, static_cast<int>(sequence_)));
          std::copy(yuyv.begin(), yuyv.end(), buf.begin());  // in place: the camera holds a mapping of it
        }
        b->bytesused = static_cast<uint32_t>(truncate_at.count(dequeues) ? buf.size() / 3 : buf.size());
        ++sequence_;
        ++dequeues;
        return 0;
      }
      default: return fail(EINVAL);
    }
  }
  void* mmap(size_t, int, int, int, off_t offset) override {
    ++mapped;
    return buffers_[static_cast<size_t>(offset / 65536)].data();
  }
  int munmap(void*, size_t) override {
    --mapped;
    return 0;
  }
  int poll(struct pollfd* fds, nfds_t, int) override {
    fds[0].revents = present ? POLLIN : POLLERR;
    return 1;
  }

 private:
  static int fail(int e) {
    errno = e;
    return -1;
  }
  std::vector<std::vector<uint8_t>> buffers_;
  std::deque<uint32_t> queue_;
  uint64_t sequence_ = 0;
  uint32_t format_ = 0;
};

TEST(V4l2Camera, StreamsDecodesAndCountsDriverDropsAndCorruptFrames) {
  auto dev = std::make_shared<ScriptedDevice>();
  dev->drop_at = {3, 4};
  dev->truncate_at = {6};
  V4l2Options o;
  o.device = "/dev/video-scripted";
  o.width = 64;
  o.height = 48;
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
  V4l2Options o;
  o.device = "/dev/video-scripted";
  o.width = 64;
  o.height = 48;
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
  V4l2Options o;
  o.device = "/dev/video-scripted";
  o.width = 64;
  o.height = 48;
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
