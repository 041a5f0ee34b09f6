#include "hxmap/openni2/openni2.hpp"

#include <OpenNI.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <mutex>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace hxmap::drv {

namespace {

// OpenNI2's last error, without its tabs and trailing newlines.
std::string oniError() {
  std::string e = openni::OpenNI::getExtendedError();
  for (char& c : e) {
    if (c == '\t' || c == '\n') c = ' ';
  }
  const size_t b = e.find_first_not_of(' '), end = e.find_last_not_of(' ');
  return b == std::string::npos ? std::string("no details") : e.substr(b, end - b + 1);
}

// OpenNI::initialize is process wide; shutdown is left to process exit
// (another camera may still be open).
Status initializeOnce() {
  static std::once_flag once;
  static openni::Status status = openni::STATUS_OK;
  static std::string error;
  std::call_once(once, [] {
    status = openni::OpenNI::initialize();
    if (status != openni::STATUS_OK) error = oniError();
  });
  if (status != openni::STATUS_OK) return Error{fmt::format("OpenNI2: initialization failed: {}", error)};
  return Status::ok();
}

alg::PinholeCamera cameraFromFov(const openni::VideoStream& s) {
  const openni::VideoMode m = s.getVideoMode();
  alg::PinholeCamera c;
  c.width = m.getResolutionX();
  c.height = m.getResolutionY();
  c.fx = 0.5 * c.width / std::tan(0.5 * s.getHorizontalFieldOfView());
  c.fy = 0.5 * c.height / std::tan(0.5 * s.getVerticalFieldOfView());
  c.cx = 0.5 * c.width - 0.5;
  c.cy = 0.5 * c.height - 0.5;
  return c;
}

// The listed mode of `format` nearest to the wanted size and rate.
bool pickMode(const openni::SensorInfo* info, openni::PixelFormat format, int w, int h, int fps, openni::VideoMode& out) {
  if (info == nullptr) return false;
  const auto& modes = info->getSupportedVideoModes();
  double best = 1e300;
  bool found = false;
  for (int i = 0; i < modes.getSize(); ++i) {
    const openni::VideoMode& m = modes[i];
    if (m.getPixelFormat() != format) continue;
    const double cost = std::abs(m.getResolutionX() - w) + std::abs(m.getResolutionY() - h) + 10.0 * std::abs(m.getFps() - fps);
    if (cost < best) {
      best = cost;
      out = m;
      found = true;
    }
  }
  return found;
}

}  // namespace

struct OpenNi2Camera::Impl {
  openni::Device device;
  openni::VideoStream color, depth;
  StreamSync sync;
  uint64_t color_frames = 0, depth_frames = 0;
  double depth_scale = 1000.0;
  explicit Impl(double max_gap_s) : sync(max_gap_s) {}
  ~Impl() {
    color.stop();
    depth.stop();
    color.destroy();
    depth.destroy();
    device.close();
  }
};

OpenNi2Camera::OpenNi2Camera(const OpenNi2Options& options) : options_(options), impl_(new Impl(options.max_gap_s)) {}
OpenNi2Camera::~OpenNi2Camera() = default;

Expected<std::unique_ptr<OpenNi2Camera>> OpenNi2Camera::open(const OpenNi2Options& o) {
  const bool oni = o.uri.size() > 4 && o.uri.compare(o.uri.size() - 4, 4, ".oni") == 0;
  if (oni) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(o.uri, ec)) return Error{fmt::format("{}: no such recording", o.uri)};
  }
  if (auto s = initializeOnce(); !s) return Error{s.message()};
  std::unique_ptr<OpenNi2Camera> cam(new OpenNi2Camera(o));
  Impl& im = *cam->impl_;
  if (!oni && o.uri.empty()) {
    openni::Array<openni::DeviceInfo> devices;
    openni::OpenNI::enumerateDevices(&devices);
    if (devices.getSize() == 0) {
      return Error{"OpenNI2: no device found (is the camera plugged in, and its udev rules installed? "
                   "a recording can be given as a .oni path)"};
    }
  }
  const char* uri = o.uri.empty() ? openni::ANY_DEVICE : o.uri.c_str();
  if (im.device.open(uri) != openni::STATUS_OK) {
    return Error{fmt::format("OpenNI2: cannot open {}: {}", o.uri.empty() ? "the first device" : o.uri,
                             oniError())};
  }
  cam->name_ = oni ? o.uri : im.device.getDeviceInfo().getName();
  cam->recording_ = im.device.isFile();
  if (im.color.create(im.device, openni::SENSOR_COLOR) != openni::STATUS_OK ||
      im.depth.create(im.device, openni::SENSOR_DEPTH) != openni::STATUS_OK) {
    return Error{fmt::format("OpenNI2: {}: needs a color and a depth stream: {}", cam->name_, oniError())};
  }
  if (!cam->recording_) {
    openni::VideoMode cm, dm;
    if (pickMode(im.device.getSensorInfo(openni::SENSOR_COLOR), openni::PIXEL_FORMAT_RGB888, o.width, o.height, o.fps, cm)) {
      im.color.setVideoMode(cm);
    }
    if (pickMode(im.device.getSensorInfo(openni::SENSOR_DEPTH), openni::PIXEL_FORMAT_DEPTH_1_MM, o.width, o.height, o.fps, dm)) {
      im.depth.setVideoMode(dm);
    }
  }
  bool registered = false;
  if (o.registration && im.device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR)) {
    registered = im.device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) == openni::STATUS_OK;
  }
  im.device.setDepthColorSyncEnabled(true);  // best effort: pairing by time follows anyway
  if (cam->recording_) {
    openni::PlaybackControl* pc = im.device.getPlaybackControl();
    if (pc != nullptr) {
      pc->setRepeatEnabled(false);
      pc->setSpeed(o.realtime_playback ? 1.0f : -1.0f);  // -1: as fast as frames are read
      cam->recording_frames_ = pc->getNumberOfFrames(im.color);
    }
  }
  if (im.color.start() != openni::STATUS_OK || im.depth.start() != openni::STATUS_OK) {
    return Error{fmt::format("OpenNI2: {}: cannot start the streams: {}", cam->name_, oniError())};
  }
  const openni::PixelFormat df = im.depth.getVideoMode().getPixelFormat();
  if (df == openni::PIXEL_FORMAT_DEPTH_100_UM) {
    im.depth_scale = 10000.0;
  } else if (df != openni::PIXEL_FORMAT_DEPTH_1_MM) {
    return Error{fmt::format("OpenNI2: {}: depth pixel format {} is not millimeters or 100 um", cam->name_, static_cast<int>(df))};
  }
  if (im.color.getVideoMode().getPixelFormat() != openni::PIXEL_FORMAT_RGB888) {
    return Error{fmt::format("OpenNI2: {}: color pixel format {} is not RGB888", cam->name_,
                             static_cast<int>(im.color.getVideoMode().getPixelFormat()))};
  }
  RigCalibration& cal = cam->calibration_;
  cal.color = cameraFromFov(im.color);
  cal.depth = registered ? cal.color : cameraFromFov(im.depth);
  cal.registered = registered && cal.depth.width == cal.color.width && cal.depth.height == cal.color.height;
  cal.depth_scale = im.depth_scale;
  spdlog::info("OpenNI2 {}: color {}x{}, depth {}x{} ({} per meter), registration {}{}", cam->name_, cal.color.width,
               cal.color.height, cal.depth.width, cal.depth.height, im.depth_scale, cal.registered ? "by the device" : "in software",
               cam->recording_ ? fmt::format(", recording of {} frames", cam->recording_frames_) : "");
  return cam;
}

Expected<SyncedPair> OpenNi2Camera::grab(double timeout_s) {
  Impl& im = *impl_;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  for (;;) {
    if (auto pair = im.sync.pop()) return std::move(*pair);
    if (recording_ && recording_frames_ > 0 && im.color_frames >= static_cast<uint64_t>(recording_frames_) &&
        im.depth_frames >= static_cast<uint64_t>(recording_frames_)) {
      return Error{fmt::format("{}: end of recording", name_)};
    }
    const int left_ms = static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now()).count());
    if (left_ms <= 0) {
      return Error{fmt::format("OpenNI2 {}: no frames for {:.1f} s ({})", name_, timeout_s,
                               recording_ ? "end of recording" : "the camera vanished or stalled")};
    }
    openni::VideoStream* streams[] = {&im.color, &im.depth};
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(streams, 2, &ready, left_ms) != openni::STATUS_OK || ready < 0) continue;
    openni::VideoFrameRef f;
    if (streams[ready]->readFrame(&f) != openni::STATUS_OK || !f.isValid()) {
      return Error{fmt::format("OpenNI2 {}: reading a frame failed: {}", name_, oniError())};
    }
    const int64_t stamp = static_cast<int64_t>(f.getTimestamp()) * 1000;  // device clock, us
    const int w = f.getWidth(), h = f.getHeight();
    if (ready == 0) {
      const cv::Mat view(h, w, CV_8UC3, const_cast<void*>(f.getData()), static_cast<size_t>(f.getStrideInBytes()));
      im.sync.pushColor(ColorImage{stamp, static_cast<uint64_t>(f.getFrameIndex()), view.clone()});
      ++im.color_frames;
    } else {
      const cv::Mat view(h, w, CV_16UC1, const_cast<void*>(f.getData()), static_cast<size_t>(f.getStrideInBytes()));
      im.sync.pushDepth(DepthImage{stamp, static_cast<uint64_t>(f.getFrameIndex()), view.clone()});
      ++im.depth_frames;
    }
  }
}

OpenNi2Stats OpenNi2Camera::stats() const { return {impl_->color_frames, impl_->depth_frames, impl_->sync.stats()}; }

}  // namespace hxmap::drv
