// A stand-in V4L2 device for tests: the system calls of a UVC camera
// (YUYV color or Z16 depth) answered from memory, with a script of drops,
// truncated buffers, unplugs and returns, and optional real-time pacing.
#pragma once

#include <fcntl.h>
#include <linux/videodev2.h>
#include <time.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <deque>
#include <functional>
#include <set>
#include <thread>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "hxmap/v4l2/camera.hpp"
#include "hxmap/v4l2/convert.hpp"

namespace hxmap::test {

using drv::encodeYuyv;

inline cv::Mat testImage(int w, int h, int k = 0) {
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


// A camera that is not there: a YUYV (and Z16) UVC device in memory whose
// script says when it drops, corrupts, unplugs and comes back. By default
// frames are ready at once with synthetic stamps (33.3 ms apart); with
// period_ns > 0 the device paces itself in real time like a camera (a frame
// every period, stamped on CLOCK_MONOTONIC from its stream start) and
// `fill` gives the content of each frame by its index in time.
class ScriptedDevice : public drv::DeviceIo {
 public:
  /// Frame content by index in time since the first stream start (the
  /// buffer is sized for the negotiated format); empty = built-in patterns.
  std::function<void(uint64_t index, std::vector<uint8_t>& buffer)> fill;
  int64_t period_ns = 0;             ///< > 0: real-time pacing
  uint64_t last_index = UINT64_MAX;  ///< paced: no frames after this index (the camera stalls)
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
      case VIDIOC_STREAMON:
        stream_on_ns_ = monotonicNs();
        if (first_stream_on_ns_ == 0) first_stream_on_ns_ = stream_on_ns_;
        return 0;
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
        const int64_t t = period_ns > 0 ? dueNs()
                                        : 1'000'000'000 + static_cast<int64_t>(sequence_) * 33'333'333;
        b->timestamp.tv_sec = t / 1'000'000'000;
        b->timestamp.tv_usec = (t % 1'000'000'000) / 1000;
        b->flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
        std::vector<uint8_t>& buf = buffers_[b->index];
        if (fill) {
          fill(period_ns > 0 ? indexAt(t) : sequence_, buf);
        } else if (format_ == V4L2_PIX_FMT_Z16) {
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
  int poll(struct pollfd* fds, nfds_t, int timeout_ms) override {
    if (present && period_ns > 0) {
      // The next frame is ready at its due time; a stalled camera never is.
      const int64_t due = dueNs();
      if (indexAt(due) > last_index) {
        std::this_thread::sleep_for(std::chrono::milliseconds(timeout_ms));
        return 0;
      }
      const int64_t wait = due - monotonicNs();
      if (wait > static_cast<int64_t>(timeout_ms) * 1'000'000) {
        std::this_thread::sleep_for(std::chrono::milliseconds(timeout_ms));
        return 0;
      }
      if (wait > 0) std::this_thread::sleep_for(std::chrono::nanoseconds(wait));
    }
    fds[0].revents = present ? POLLIN : POLLERR;
    return 1;
  }
  /// Paced: the stamp of the first frame (index 0).
  int64_t firstStreamOnNs() const { return first_stream_on_ns_; }

 private:
  static int64_t monotonicNs() {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
  }
  int64_t dueNs() const { return stream_on_ns_ + static_cast<int64_t>(sequence_) * period_ns; }
  uint64_t indexAt(int64_t t) const { return static_cast<uint64_t>((t - first_stream_on_ns_) / period_ns); }
  static int fail(int e) {
    errno = e;
    return -1;
  }
  std::vector<std::vector<uint8_t>> buffers_;
  std::deque<uint32_t> queue_;
  uint64_t sequence_ = 0;
  uint32_t format_ = 0;
  int64_t stream_on_ns_ = 0, first_stream_on_ns_ = 0;
};

}  // namespace hxmap::test
