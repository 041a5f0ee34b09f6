#include "hxmap/v4l2/camera.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace hxmap::drv {

namespace {

class SystemIo : public DeviceIo {
 public:
  int open(const char* path, int flags) override { return ::open(path, flags); }
  int close(int fd) override { return ::close(fd); }
  int ioctl(int fd, unsigned long request, void* arg) override {
    int r;
    do {
      r = ::ioctl(fd, request, arg);
    } while (r == -1 && errno == EINTR);
    return r;
  }
  void* mmap(size_t length, int prot, int flags, int fd, off_t offset) override {
    return ::mmap(nullptr, length, prot, flags, fd, offset);
  }
  int munmap(void* addr, size_t length) override { return ::munmap(addr, length); }
  int poll(struct pollfd* fds, nfds_t n, int timeout_ms) override { return ::poll(fds, n, timeout_ms); }
};

int64_t monotonicNs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

bool deviceGone(int err) { return err == ENODEV || err == EIO || err == ENXIO || err == EBADF; }

}  // namespace

std::shared_ptr<DeviceIo> systemIo() { return std::make_shared<SystemIo>(); }

Expected<std::unique_ptr<V4l2Camera>> V4l2Camera::open(const V4l2Options& options, std::shared_ptr<DeviceIo> io) {
  if (options.formats.empty()) return Error{fmt::format("{}: no pixel formats asked for", options.device)};
  if (options.buffers < 2 || options.buffers > 32) {
    return Error{fmt::format("{}: {} buffers asked for; use 2 to 32", options.device, options.buffers)};
  }
  std::unique_ptr<V4l2Camera> cam(new V4l2Camera(options, std::move(io)));
  if (auto s = cam->start(); !s) return Error{s.message()};
  return cam;
}

V4l2Camera::~V4l2Camera() { stop(); }

Status V4l2Camera::xioctl(unsigned long request, void* arg, const char* name) {
  if (io_->ioctl(fd_, request, arg) == 0) return Status::ok();
  const int err = errno;
  return Error{fmt::format("{}: {} failed: {}", options_.device, name, std::strerror(err))};
}

Status V4l2Camera::start() {
  const std::string& dev = options_.device;
  fd_ = io_->open(dev.c_str(), O_RDWR | O_NONBLOCK);
  if (fd_ < 0) {
    const int err = errno;
    return Error{fmt::format("{}: cannot open the camera: {}{}", dev, std::strerror(err),
                             err == ENOENT ? " (is it plugged in? see `ls /dev/video*`)"
                             : err == EACCES ? " (add the user to the 'video' group)"
                                             : "")};
  }
  v4l2_capability cap{};
  if (io_->ioctl(fd_, VIDIOC_QUERYCAP, &cap) != 0) {
    const int err = errno;
    stop();
    return Error{fmt::format("{}: not a V4L2 device ({})", dev, std::strerror(err))};
  }
  card_ = reinterpret_cast<const char*>(cap.card);
  const uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING)) {
    stop();
    return Error{fmt::format("{} ({}): not a streaming capture device (a metadata or output node? try the next /dev/video*)",
                             dev, card_)};
  }
  // Format: the first wanted one the driver takes as it is.
  std::string tried;
  bool negotiated = false;
  for (PixelFormat f : options_.formats) {
    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    fmt.fmt.pix.width = static_cast<uint32_t>(options_.width);
    fmt.fmt.pix.height = static_cast<uint32_t>(options_.height);
    fmt.fmt.pix.pixelformat = fourccOf(f);
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    if (io_->ioctl(fd_, VIDIOC_S_FMT, &fmt) != 0) {
      const int err = errno;
      if (err == EBUSY) {
        stop();
        return Error{fmt::format("{} ({}): busy (another program is streaming from it)", dev, card_)};
      }
      tried += fmt::format(" {} ({})", formatName(f), std::strerror(err));
      continue;
    }
    if (fmt.fmt.pix.pixelformat != fourccOf(f)) {
      tried += fmt::format(" {} (offered {} instead)", formatName(f), fourccText(fmt.fmt.pix.pixelformat));
      continue;
    }
    format_ = f;
    width_ = static_cast<int>(fmt.fmt.pix.width);
    height_ = static_cast<int>(fmt.fmt.pix.height);
    bytes_per_line_ = fmt.fmt.pix.bytesperline;
    negotiated = true;
    break;
  }
  if (!negotiated) {
    stop();
    return Error{fmt::format("{} ({}): none of the wanted formats is available:{}", dev, card_, tried)};
  }
  if (width_ != options_.width || height_ != options_.height) {
    spdlog::warn("{}: asked for {}x{}, the camera streams {}x{}", dev, options_.width, options_.height, width_, height_);
  }
  if (options_.fps > 0) {
    v4l2_streamparm parm{};
    parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    parm.parm.capture.timeperframe.numerator = 1000;
    parm.parm.capture.timeperframe.denominator = static_cast<uint32_t>(std::lround(options_.fps * 1000));
    if (io_->ioctl(fd_, VIDIOC_S_PARM, &parm) != 0) spdlog::warn("{}: cannot set the frame rate: {}", dev, std::strerror(errno));
  }
  v4l2_requestbuffers req{};
  req.count = static_cast<uint32_t>(options_.buffers);
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (auto s = xioctl(VIDIOC_REQBUFS, &req, "requesting mmap buffers (VIDIOC_REQBUFS)"); !s) {
    stop();
    return s;
  }
  if (req.count < 2) {
    stop();
    return Error{fmt::format("{}: the driver gave {} buffer(s); streaming needs 2", dev, req.count)};
  }
  for (uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = i;
    if (auto s = xioctl(VIDIOC_QUERYBUF, &buf, "VIDIOC_QUERYBUF"); !s) {
      stop();
      return s;
    }
    void* p = io_->mmap(buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, static_cast<off_t>(buf.m.offset));
    if (p == MAP_FAILED) {
      const int err = errno;
      stop();
      return Error{fmt::format("{}: cannot map buffer {}: {}", dev, i, std::strerror(err))};
    }
    buffers_.push_back({p, buf.length});
    if (auto s = xioctl(VIDIOC_QBUF, &buf, "VIDIOC_QBUF"); !s) {
      stop();
      return s;
    }
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (auto s = xioctl(VIDIOC_STREAMON, &type, "starting the stream (VIDIOC_STREAMON)"); !s) {
    stop();
    return s;
  }
  have_sequence_ = false;
  spdlog::info("{} ({}): {} {}x{} at {:.0f} fps requested, {} buffers", dev, card_, formatName(format_), width_, height_,
               options_.fps, buffers_.size());
  return Status::ok();
}

void V4l2Camera::stop() {
  if (fd_ >= 0) {
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    io_->ioctl(fd_, VIDIOC_STREAMOFF, &type);  // fails harmlessly when the device is gone
  }
  for (const Buffer& b : buffers_) io_->munmap(b.start, b.length);
  buffers_.clear();
  if (fd_ >= 0) io_->close(fd_);
  fd_ = -1;
}

Status V4l2Camera::reconnect() {
  spdlog::warn("{}: the camera disappeared; reconnecting for up to {:.1f} s", options_.device, options_.reconnect_timeout_s);
  stop();
  const auto t0 = std::chrono::steady_clock::now();
  std::string last;
  for (;;) {
    const double away = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (away > options_.reconnect_timeout_s) {
      stats_.disconnected_s += away;
      return Error{fmt::format("{}: the camera disappeared and did not come back within {:.1f} s (last: {})",
                               options_.device, options_.reconnect_timeout_s, last)};
    }
    if (auto s = start(); s) {
      stats_.disconnected_s += away;
      ++stats_.reconnects;
      const uint64_t lost = options_.fps > 0 ? static_cast<uint64_t>(std::floor(away * options_.fps)) : 0;
      stats_.lost_while_disconnected += lost;
      sequence_ += lost;  // the gap shows in the sequence numbers downstream
      spdlog::warn("{}: reconnected after {:.2f} s (about {} frames lost)", options_.device, away, lost);
      return Status::ok();
    } else {
      last = s.message();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

Expected<V4l2Frame> V4l2Camera::grab(double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  for (;;) {
    if (fd_ < 0) {
      if (auto s = reconnect(); !s) return Error{s.message()};
    }
    const double left = std::chrono::duration<double>(deadline - std::chrono::steady_clock::now()).count();
    if (left <= 0) return Error{fmt::format("{}: no frame within {:.1f} s", options_.device, timeout_s)};
    pollfd p{fd_, POLLIN, 0};
    const int r = io_->poll(&p, 1, static_cast<int>(std::ceil(left * 1000)));
    if (r < 0) {
      if (errno == EINTR) continue;
      if (auto s = reconnect(); !s) return Error{s.message()};
      continue;
    }
    if (r == 0) continue;  // the deadline check above ends the wait
    if (p.revents & (POLLERR | POLLHUP | POLLNVAL)) {
      if (auto s = reconnect(); !s) return Error{s.message()};
      continue;
    }
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    if (io_->ioctl(fd_, VIDIOC_DQBUF, &buf) != 0) {
      const int err = errno;
      if (err == EAGAIN) continue;
      if (deviceGone(err)) {
        if (auto s = reconnect(); !s) return Error{s.message()};
        continue;
      }
      return Error{fmt::format("{}: VIDIOC_DQBUF failed: {}", options_.device, std::strerror(err))};
    }
    const int64_t dequeued_ns = monotonicNs();
    if (buf.index >= buffers_.size()) return Error{fmt::format("{}: the driver returned buffer {} of {}", options_.device, buf.index, buffers_.size())};
    // Sequence: jumps are frames the driver dropped.
    if (have_sequence_ && buf.sequence > last_driver_sequence_ + 1) {
      const uint64_t lost = buf.sequence - last_driver_sequence_ - 1;
      stats_.lost_by_driver += lost;
      sequence_ += lost;
    }
    have_sequence_ = true;
    last_driver_sequence_ = buf.sequence;
    const bool monotonic = (buf.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
    const int64_t stamp = monotonic ? int64_t{buf.timestamp.tv_sec} * 1'000'000'000 + int64_t{buf.timestamp.tv_usec} * 1000
                                    : dequeued_ns;
    const uint8_t* data = static_cast<const uint8_t*>(buffers_[buf.index].start);
    const size_t bytes = std::min<size_t>(buf.bytesused, buffers_[buf.index].length);
    Expected<cv::Mat> image = isDepthFormat(format_) ? decodeDepth(data, bytes, width_, height_, bytes_per_line_)
                                                     : decodeColor(format_, data, bytes, width_, height_, bytes_per_line_);
    const bool error_flag = (buf.flags & V4L2_BUF_FLAG_ERROR) != 0;
    // The buffer goes back to the driver whatever happened to its content.
    if (io_->ioctl(fd_, VIDIOC_QBUF, &buf) != 0) {
      const int err = errno;
      if (deviceGone(err)) {
        if (auto s = reconnect(); !s) return Error{s.message()};
        continue;
      }
      return Error{fmt::format("{}: VIDIOC_QBUF failed: {}", options_.device, std::strerror(err))};
    }
    const uint64_t seq = sequence_++;
    if (!image || error_flag) {
      ++stats_.corrupt;
      spdlog::warn("{}: frame {} skipped: {}", options_.device, seq,
                   image ? std::string("the driver flagged the buffer as corrupt") : image.message());
      continue;
    }
    ++stats_.frames;
    return V4l2Frame{stamp, seq, std::move(*image)};
  }
}

}  // namespace hxmap::drv
