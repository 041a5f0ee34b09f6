// A V4L2 capture device (UVC color or depth camera) streaming through
// mmap buffers.
//
// open(): checks the device is a streaming capture device, negotiates the
// first of the wanted formats it accepts at the wanted size (the driver may
// adjust the size: the size it picked is used and logged), asks for the
// frame rate, maps `buffers` buffers, queues them and starts streaming.
// grab(): waits for the next buffer, decodes it (a corrupt or truncated
// frame is counted and skipped, never fatal) and requeues the buffer. Time
// stamps come from the buffer (the driver's CLOCK_MONOTONIC capture time, in
// ns); a driver without monotonic stamps gets the dequeue time instead.
// Frames the driver lost show as jumps in its sequence numbers and are
// counted. When the device disappears (unplugged: ENODEV/EIO), grab()
// closes it and reopens the same path until `reconnect_timeout_s` passes;
// the frames lost while away are counted as a gap.
//
// The system calls go through DeviceIo so that tests can stand in for a
// device that is not there; the real one is systemIo().
//
// Thread safety: one thread per camera.
#pragma once

#include <poll.h>
#include <sys/types.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "hxmap/core/expected.hpp"
#include "hxmap/v4l2/convert.hpp"

namespace hxmap::drv {

/// The system calls a V4L2 camera makes (errno set on failure, as the calls).
class DeviceIo {
 public:
  virtual ~DeviceIo() = default;
  virtual int open(const char* path, int flags) = 0;
  virtual int close(int fd) = 0;
  virtual int ioctl(int fd, unsigned long request, void* arg) = 0;
  virtual void* mmap(size_t length, int prot, int flags, int fd, off_t offset) = 0;
  virtual int munmap(void* addr, size_t length) = 0;
  virtual int poll(struct pollfd* fds, nfds_t n, int timeout_ms) = 0;
};
std::shared_ptr<DeviceIo> systemIo();

struct V4l2Options {
  std::string device = "/dev/video0";
  int width = 640, height = 480;
  double fps = 30;
  /// In order of preference.
  std::vector<PixelFormat> formats{PixelFormat::kYuyv, PixelFormat::kMjpeg, PixelFormat::kRgb24};
  int buffers = 4;
  double reconnect_timeout_s = 5;
};

struct V4l2Frame {
  int64_t stamp_ns = 0;   ///< capture time, CLOCK_MONOTONIC
  uint64_t sequence = 0;  ///< continues across reconnects
  cv::Mat image;          ///< CV_8UC3 RGB, or CV_16UC1 for depth formats
};

struct V4l2Stats {
  uint64_t frames = 0;
  uint64_t lost_by_driver = 0;   ///< sequence number jumps
  uint64_t corrupt = 0;          ///< buffers that did not decode (skipped)
  uint64_t reconnects = 0;
  double disconnected_s = 0;     ///< time spent away
  uint64_t lost_while_disconnected = 0;  ///< frames the time away held, at the stream's rate
};

class V4l2Camera {
 public:
  static Expected<std::unique_ptr<V4l2Camera>> open(const V4l2Options& options,
                                                     std::shared_ptr<DeviceIo> io = systemIo());
  ~V4l2Camera();
  V4l2Camera(const V4l2Camera&) = delete;
  V4l2Camera& operator=(const V4l2Camera&) = delete;

  /// The next frame. Errors: no frame within timeout_s (the device is there
  /// but silent), or the device gone for longer than reconnect_timeout_s.
  Expected<V4l2Frame> grab(double timeout_s = 1.0);

  PixelFormat format() const { return format_; }
  int width() const { return width_; }
  int height() const { return height_; }
  const std::string& device() const { return options_.device; }
  const std::string& card() const { return card_; }
  const V4l2Stats& stats() const { return stats_; }

 private:
  V4l2Camera(const V4l2Options& options, std::shared_ptr<DeviceIo> io) : options_(options), io_(std::move(io)) {}
  Status start();  ///< open, negotiate, map, stream on
  void stop();     ///< stream off, unmap, close
  Status reconnect();
  Status xioctl(unsigned long request, void* arg, const char* name);

  V4l2Options options_;
  std::shared_ptr<DeviceIo> io_;
  int fd_ = -1;
  std::string card_;
  PixelFormat format_ = PixelFormat::kYuyv;
  int width_ = 0, height_ = 0;
  size_t bytes_per_line_ = 0;
  struct Buffer {
    void* start = nullptr;
    size_t length = 0;
  };
  std::vector<Buffer> buffers_;
  bool have_sequence_ = false;
  uint32_t last_driver_sequence_ = 0;
  uint64_t sequence_ = 0;
  V4l2Stats stats_;
};

}  // namespace hxmap::drv
