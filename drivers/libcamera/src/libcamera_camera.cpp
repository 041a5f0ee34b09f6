#include "hxmap/libcamera_drv/libcamera_camera.hpp"

#include <sys/mman.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>

#include <fmt/format.h>
#include <libcamera/libcamera.h>
#include <spdlog/spdlog.h>

#include "hxmap/v4l2/convert.hpp"

namespace hxmap::drv {

namespace lc = libcamera;

struct LibcameraCamera::Impl {
  std::unique_ptr<lc::CameraManager> manager;
  std::shared_ptr<lc::Camera> camera;
  bool acquired = false, started = false;
  std::unique_ptr<lc::CameraConfiguration> config;
  lc::Stream* stream = nullptr;
  std::unique_ptr<lc::FrameBufferAllocator> allocator;
  std::vector<std::unique_ptr<lc::Request>> requests;
  struct Mapping {
    void* start = MAP_FAILED;
    size_t length = 0;
  };
  std::vector<Mapping> mappings;  ///< one per buffer (first plane; packed formats have one); a request's cookie indexes it
  std::string id;
  int width = 0, height = 0;
  unsigned stride = 0;
  lc::PixelFormat format;

  std::mutex mutex;
  std::condition_variable cv;
  std::deque<lc::Request*> completed;
  bool removed = false;
  LibcameraStats stats;
  bool have_sequence = false;
  unsigned last_sequence = 0;

  void onRequest(lc::Request* r) {
    std::lock_guard<std::mutex> lock(mutex);
    completed.push_back(r);
    cv.notify_one();
  }
  void onRemoved(std::shared_ptr<lc::Camera> cam) {
    if (cam != camera) return;
    std::lock_guard<std::mutex> lock(mutex);
    removed = true;
    cv.notify_one();
  }

  ~Impl() {
    if (started) camera->stop();
    if (camera) camera->requestCompleted.disconnect(this);
    requests.clear();
    for (const Mapping& m : mappings) {
      if (m.start != MAP_FAILED) munmap(m.start, m.length);
    }
    if (allocator && stream) allocator->free(stream);
    allocator.reset();
    if (acquired) camera->release();
    camera.reset();
    if (manager) manager->stop();
  }
};

LibcameraCamera::LibcameraCamera() : impl_(new Impl) {}
LibcameraCamera::~LibcameraCamera() = default;
const std::string& LibcameraCamera::id() const { return impl_->id; }
int LibcameraCamera::width() const { return impl_->width; }
int LibcameraCamera::height() const { return impl_->height; }
LibcameraStats LibcameraCamera::stats() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->stats;
}

Expected<std::unique_ptr<LibcameraCamera>> LibcameraCamera::open(const LibcameraOptions& o) {
  std::unique_ptr<LibcameraCamera> cam(new LibcameraCamera);
  Impl& im = *cam->impl_;
  im.manager = std::make_unique<lc::CameraManager>();
  if (const int r = im.manager->start(); r != 0) {
    im.manager.reset();
    return Error{fmt::format("libcamera: the camera manager did not start: {}", strerror(-r))};
  }
  const auto cameras = im.manager->cameras();
  if (cameras.empty()) return Error{"libcamera: no camera found (is the sensor connected and its overlay enabled?)"};
  if (o.camera_id.empty()) {
    im.camera = cameras.front();
  } else {
    im.camera = im.manager->get(o.camera_id);
    if (!im.camera) {
      std::string ids;
      for (const auto& c : cameras) ids += " " + c->id();
      return Error{fmt::format("libcamera: no camera '{}' (found:{})", o.camera_id, ids)};
    }
  }
  im.id = im.camera->id();
  if (im.camera->acquire() != 0) return Error{fmt::format("libcamera: camera '{}' is in use by another program", im.id)};
  im.acquired = true;
  im.config = im.camera->generateConfiguration({lc::StreamRole::VideoRecording});
  if (!im.config || im.config->size() != 1) return Error{fmt::format("libcamera: camera '{}' offers no video stream", im.id)};
  lc::StreamConfiguration& sc = im.config->at(0);
  sc.size = lc::Size(static_cast<unsigned>(o.width), static_cast<unsigned>(o.height));
  sc.bufferCount = static_cast<unsigned>(std::max(o.buffers, 2));
  // Bytes R,G,B (DRM's BGR888), else B,G,R, else YUYV.
  bool format_ok = false;
  for (const lc::PixelFormat& f : {lc::formats::BGR888, lc::formats::RGB888, lc::formats::YUYV}) {
    sc.pixelFormat = f;
    if (im.config->validate() != lc::CameraConfiguration::Invalid && sc.pixelFormat == f) {
      format_ok = true;
      break;
    }
  }
  if (!format_ok) {
    return Error{fmt::format("libcamera: camera '{}' streams none of RGB888, BGR888, YUYV (offers {})", im.id,
                             sc.pixelFormat.toString())};
  }
  if (im.camera->configure(im.config.get()) != 0) return Error{fmt::format("libcamera: cannot configure camera '{}'", im.id)};
  im.stream = sc.stream();
  im.width = static_cast<int>(sc.size.width);
  im.height = static_cast<int>(sc.size.height);
  im.stride = sc.stride;
  im.format = sc.pixelFormat;
  if (im.width != o.width || im.height != o.height) {
    spdlog::warn("libcamera {}: asked for {}x{}, the camera streams {}x{}", im.id, o.width, o.height, im.width, im.height);
  }
  im.allocator = std::make_unique<lc::FrameBufferAllocator>(im.camera);
  if (im.allocator->allocate(im.stream) < 0) return Error{fmt::format("libcamera: cannot allocate buffers for '{}'", im.id)};
  for (const auto& buffer : im.allocator->buffers(im.stream)) {
    const lc::FrameBuffer::Plane& plane = buffer->planes()[0];
    size_t length = plane.length;
    const size_t offset = plane.offset == lc::FrameBuffer::Plane::kInvalidOffset ? 0 : plane.offset;
    void* p = mmap(nullptr, offset + length, PROT_READ, MAP_SHARED, plane.fd.get(), 0);
    if (p == MAP_FAILED) return Error{fmt::format("libcamera: cannot map a buffer of '{}': {}", im.id, strerror(errno))};
    im.mappings.push_back({p, offset + length});
    std::unique_ptr<lc::Request> req = im.camera->createRequest(im.mappings.size() - 1);
    if (!req || req->addBuffer(im.stream, buffer.get()) != 0) {
      return Error{fmt::format("libcamera: cannot make a capture request for '{}'", im.id)};
    }
    im.requests.push_back(std::move(req));
  }
  im.camera->requestCompleted.connect(&im, &Impl::onRequest);
  im.manager->cameraRemoved.connect(&im, &Impl::onRemoved);
  if (im.camera->start() != 0) return Error{fmt::format("libcamera: cannot start camera '{}'", im.id)};
  im.started = true;
  for (auto& r : im.requests) {
    if (im.camera->queueRequest(r.get()) != 0) return Error{fmt::format("libcamera: cannot queue a request on '{}'", im.id)};
  }
  spdlog::info("libcamera {}: {} {}x{}, {} buffers", im.id, im.format.toString(), im.width, im.height, im.requests.size());
  return cam;
}

Expected<LibcameraFrame> LibcameraCamera::grab(double timeout_s) {
  Impl& im = *impl_;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  for (;;) {
    lc::Request* req = nullptr;
    {
      std::unique_lock<std::mutex> lock(im.mutex);
      if (!im.cv.wait_until(lock, deadline, [&] { return !im.completed.empty() || im.removed; })) {
        return Error{fmt::format("libcamera {}: no frame within {:.1f} s", im.id, timeout_s)};
      }
      if (im.removed) return Error{fmt::format("libcamera {}: the camera was removed", im.id)};
      req = im.completed.front();
      im.completed.pop_front();
    }
    if (req->status() == lc::Request::RequestCancelled) {
      return Error{fmt::format("libcamera {}: capture cancelled (the camera stopped or vanished)", im.id)};
    }
    const lc::FrameBuffer* buffer = req->findBuffer(im.stream);
    const lc::FrameMetadata& md = buffer->metadata();
    LibcameraFrame frame;
    frame.stamp_ns = static_cast<int64_t>(md.timestamp);
    frame.sequence = md.sequence;
    bool ok = md.status == lc::FrameMetadata::FrameSuccess;
    std::string why = ok ? "" : "the camera flagged the frame as failed";
    if (ok) {
      const Impl::Mapping& m = im.mappings[req->cookie()];
      const lc::FrameBuffer::Plane& plane = buffer->planes()[0];
      const size_t offset = plane.offset == lc::FrameBuffer::Plane::kInvalidOffset ? 0 : plane.offset;
      const uint8_t* data = static_cast<const uint8_t*>(m.start) + offset;
      const size_t bytes = std::min<size_t>(md.planes()[0].bytesused, plane.length);
      Expected<cv::Mat> image = im.format == lc::formats::YUYV
                                    ? decodeColor(PixelFormat::kYuyv, data, bytes, im.width, im.height, im.stride)
                                    : decodeColor(PixelFormat::kRgb24, data, bytes, im.width, im.height, im.stride);
      if (image && im.format == lc::formats::RGB888) {  // bytes B,G,R
        cv::Mat& rgb = *image;
        for (int v = 0; v < rgb.rows; ++v) {
          uint8_t* p = rgb.ptr<uint8_t>(v);
          for (int u = 0; u < rgb.cols; ++u, p += 3) std::swap(p[0], p[2]);
        }
      }
      if (image) {
        frame.rgb = std::move(*image);
      } else {
        ok = false;
        why = image.message();
      }
    }
    req->reuse(lc::Request::ReuseBuffers);
    if (im.camera->queueRequest(req) != 0) return Error{fmt::format("libcamera {}: cannot requeue a request", im.id)};
    std::lock_guard<std::mutex> lock(im.mutex);
    if (im.have_sequence && frame.sequence > im.last_sequence + 1) im.stats.lost_by_driver += frame.sequence - im.last_sequence - 1;
    im.have_sequence = true;
    im.last_sequence = static_cast<unsigned>(frame.sequence);
    if (!ok) {
      ++im.stats.failed;
      spdlog::warn("libcamera {}: frame {} skipped: {}", im.id, frame.sequence, why);
      continue;
    }
    ++im.stats.frames;
    return frame;
  }
}

}  // namespace hxmap::drv
