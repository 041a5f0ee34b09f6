#include "hxmap/camera/camera_source.hpp"

#include <pthread.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "hxmap/ring/spsc_ring.hpp"

#ifdef HXMAP_HAVE_OPENNI2
#include "hxmap/openni2/openni2.hpp"
#endif
#ifdef HXMAP_HAVE_LIBCAMERA
#include "hxmap/libcamera_drv/libcamera_camera.hpp"
#endif

namespace hxmap::rt {

namespace {

using Clock = std::chrono::steady_clock;

constexpr const char* kSpecForms =
    "v4l2:COLOR_DEV+DEPTH_DEV (e.g. v4l2:/dev/video4+/dev/video2), openni2[:URI or .oni file], "
    "libcamera[:ID]+v4l2:DEPTH_DEV";

[[maybe_unused]] double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

/// One stream read by its own thread: grab (blocking in the driver, at most
/// about half a second) and push into a bounded ring for the sensor thread.
/// Errors are counted and logged (at most once a second); the stream counts
/// as lost when it has delivered nothing for lost_timeout_s.
template <typename Image>
class Grabber {
 public:
  using GrabFn = std::function<Expected<Image>()>;
  Grabber(std::string thread_name, std::string device, GrabFn grab, size_t capacity, std::atomic<uint64_t>& wake)
      : thread_name_(std::move(thread_name)), device_(std::move(device)), grab_(std::move(grab)), ring_(capacity),
        wake_(wake) {}
  ~Grabber() { stop(); }
  Grabber(const Grabber&) = delete;
  Grabber& operator=(const Grabber&) = delete;

  void start() {
    last_frame_ns_.store(nowNs());
    thread_ = std::thread([this] { loop(); });
  }
  void stop() {
    stop_.store(true);
    if (thread_.joinable()) thread_.join();
  }
  bool tryPop(Image& out) { return ring_.tryPop(out); }
  double silentForS() const { return static_cast<double>(nowNs() - last_frame_ns_.load()) * 1e-9; }
  uint64_t frames() const { return frames_.load(); }
  uint64_t ringFull() const { return ring_full_.load(); }
  uint64_t errors() const { return errors_.load(); }
  const std::string& device() const { return device_; }

 private:
  static int64_t nowNs() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
  }
  void loop() {
    pthread_setname_np(pthread_self(), thread_name_.c_str());
    Clock::time_point last_log{};
    while (!stop_.load()) {
      Expected<Image> image = grab_();
      if (image) {
        last_frame_ns_.store(nowNs());
        frames_.fetch_add(1);
        if (!ring_.tryPush(std::move(*image))) ring_full_.fetch_add(1);
      } else {
        errors_.fetch_add(1);
        if (Clock::now() - last_log > std::chrono::seconds(1)) {
          spdlog::warn("{}", image.message());
          last_log = Clock::now();
        }
      }
      // Also after an error: the sensor thread re-checks stop and silence.
      wake_.fetch_add(1, std::memory_order_release);
      wake_.notify_all();
    }
  }

  std::string thread_name_, device_;
  GrabFn grab_;
  SpscRing<Image> ring_;
  std::atomic<uint64_t>& wake_;
  std::atomic<bool> stop_{false};
  std::atomic<int64_t> last_frame_ns_{0};
  std::atomic<uint64_t> frames_{0}, ring_full_{0}, errors_{0};
  std::thread thread_;
};

/// Color and depth from two devices, each with its grabber thread.
class TwoStreamSource final : public CameraSource {
 public:
  TwoStreamSource(std::string name, const CameraSourceOptions& options, drv::FrameAssembler assembler,
                  Grabber<drv::ColorImage>::GrabFn grab_color, std::string color_device,
                  Grabber<drv::DepthImage>::GrabFn grab_depth, std::string depth_device,
                  std::function<std::string()> driver_stats)
      : name_(std::move(name)), options_(options), assembler_(std::move(assembler)), sync_(options.max_sync_gap_s),
        color_("hx-grab-color", std::move(color_device), std::move(grab_color),
               static_cast<size_t>(options.ring_capacity), wake_),
        depth_("hx-grab-depth", std::move(depth_device), std::move(grab_depth),
               static_cast<size_t>(options.ring_capacity), wake_),
        driver_stats_(std::move(driver_stats)) {}
  ~TwoStreamSource() override { stopGrabbers(); }

  Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) override {
    if (!started_) {
      color_.start();
      depth_.start();
      started_ = true;
    }
    for (;;) {
      const uint64_t seen = wake_.load(std::memory_order_acquire);
      drv::ColorImage c;
      while (color_.tryPop(c)) sync_.pushColor(std::move(c));
      drv::DepthImage d;
      while (depth_.tryPop(d)) sync_.pushDepth(std::move(d));
      while (auto pair = sync_.pop()) {
        auto frame = assembler_.assemble(pair->color, pair->depth, seq_);
        if (!frame) {
          // A frame of the wrong size or type: counted and skipped.
          ++bad_frames_;
          spdlog::warn("{}: frame skipped: {}", name_, frame.message());
          continue;
        }
        ++seq_;
        return std::optional<RgbdFrame>{std::move(*frame)};
      }
      if (stop.load()) {
        stopGrabbers();
        return std::optional<RgbdFrame>{};
      }
      if (color_.silentForS() > options_.lost_timeout_s) return lost(color_.device(), "color");
      if (depth_.silentForS() > options_.lost_timeout_s) return lost(depth_.device(), "depth");
      // Woken by every grab, and by every failed grab (at most about half a
      // second apart), so stop and silence are re-checked without polling.
      wake_.wait(seen, std::memory_order_acquire);
    }
  }
  double fps() const override { return options_.fps; }
  const alg::PinholeCamera& camera() const override { return assembler_.camera(); }
  std::string name() const override { return name_; }
  std::string statsText() const override {
    const drv::SyncStats& s = sync_.stats();
    std::string text = fmt::format(
        "{}: {} color and {} depth images, {} pairs (widest gap {:.1f} ms); dropped: {} color without depth, {} depth "
        "unpaired, {} out of order, {} while the sensor thread was behind, {} unusable; grab errors {}",
        name_, color_.frames(), depth_.frames(), s.pairs, 1000 * s.max_gap_paired_s, s.color_dropped, s.depth_dropped,
        s.out_of_order, color_.ringFull() + depth_.ringFull(), bad_frames_, color_.errors() + depth_.errors());
    if (driver_stats_) text += "; " + driver_stats_();
    return text;
  }

 private:
  /// The grabbers stop (and release the devices' threads) when the stream
  /// ends, so statsText() afterwards reads settled counters.
  void stopGrabbers() {
    color_.stop();
    depth_.stop();
  }
  Expected<std::optional<RgbdFrame>> lost(const std::string& device, const char* stream) {
    stopGrabbers();
    return Error{fmt::format("{}: the {} stream delivered nothing for {:.1f} s (camera.lost_timeout_s); the camera is "
                             "gone or stalled",
                             device, stream, options_.lost_timeout_s)};
  }

  std::string name_;
  CameraSourceOptions options_;
  drv::FrameAssembler assembler_;
  drv::StreamSync sync_;
  std::atomic<uint64_t> wake_{0};
  Grabber<drv::ColorImage> color_;
  Grabber<drv::DepthImage> depth_;
  std::function<std::string()> driver_stats_;
  bool started_ = false;
  uint64_t seq_ = 0, bad_frames_ = 0;
};

#ifdef HXMAP_HAVE_V4L2
std::string v4l2StatsText(const drv::V4l2Camera& cam) {
  const drv::V4l2Stats& s = cam.stats();
  return fmt::format("{} ({}): {} lost by the driver, {} corrupt, {} reconnects ({:.1f} s away, about {} frames)",
                     cam.device(), cam.card(), s.lost_by_driver, s.corrupt, s.reconnects, s.disconnected_s,
                     s.lost_while_disconnected);
}

Expected<std::shared_ptr<drv::V4l2Camera>> openV4l2(const std::string& device, bool depth, int width, int height,
                                                    const CameraSourceOptions& o, std::shared_ptr<drv::DeviceIo> io) {
  drv::V4l2Options vo;
  vo.device = device;
  vo.width = width;
  vo.height = height;
  vo.fps = o.fps;
  vo.reconnect_timeout_s = o.reconnect_timeout_s;
  if (depth) vo.formats = {drv::PixelFormat::kZ16};
  auto cam = drv::V4l2Camera::open(vo, std::move(io));
  if (!cam) return Error{cam.message()};
  std::shared_ptr<drv::V4l2Camera> shared = std::move(*cam);
  if (shared->width() != width || shared->height() != height) {
    const char* key = depth ? "rig.depth_width/depth_height" : "rig.color_width/color_height";
    return Error{fmt::format("{} ({}): the camera streams {}x{}, but {} say {}x{}: calibrate the rig at the size the "
                             "camera gives",
                             device, shared->card(), shared->width(), shared->height(), key, width, height)};
  }
  return shared;
}

Grabber<drv::DepthImage>::GrabFn v4l2DepthGrab(std::shared_ptr<drv::V4l2Camera> cam) {
  return [cam]() -> Expected<drv::DepthImage> {
    auto f = cam->grab(0.5);
    if (!f) return Error{f.message()};
    return drv::DepthImage{f->stamp_ns, f->sequence, std::move(f->image)};
  };
}
#endif

#ifdef HXMAP_HAVE_OPENNI2
/// OpenNI2 pairs its streams itself: next() reads the device directly.
class OpenNi2Source final : public CameraSource {
 public:
  OpenNi2Source(std::unique_ptr<drv::OpenNi2Camera> cam, drv::FrameAssembler assembler, const CameraSourceOptions& o)
      : cam_(std::move(cam)), assembler_(std::move(assembler)), options_(o) {}
  Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) override {
    const auto since = Clock::now();
    while (!stop.load()) {
      auto pair = cam_->grab(0.5);
      if (!pair) {
        if (cam_->isRecording()) return std::optional<RgbdFrame>{};  // the recording ended
        ++errors_;
        if (secondsSince(since) > options_.lost_timeout_s) {
          return Error{fmt::format("{}: nothing for {:.1f} s (camera.lost_timeout_s): {}", cam_->name(),
                                   options_.lost_timeout_s, pair.message())};
        }
        continue;
      }
      auto frame = assembler_.assemble(pair->color, pair->depth, seq_);
      if (!frame) {
        ++bad_frames_;
        spdlog::warn("{}: frame skipped: {}", cam_->name(), frame.message());
        continue;
      }
      ++seq_;
      return std::optional<RgbdFrame>{std::move(*frame)};
    }
    return std::optional<RgbdFrame>{};
  }
  double fps() const override { return options_.fps; }
  size_t size() const override { return static_cast<size_t>(cam_->recordingFrames()); }
  const alg::PinholeCamera& camera() const override { return assembler_.camera(); }
  std::string name() const override { return cam_->name(); }
  std::string statsText() const override {
    const drv::OpenNi2Stats s = cam_->stats();
    return fmt::format("{}: {} color and {} depth frames, {} pairs; dropped {} color without depth, {} depth unpaired; "
                       "{} unusable, {} grab errors",
                       cam_->name(), s.color_frames, s.depth_frames, s.sync.pairs, s.sync.color_dropped,
                       s.sync.depth_dropped, bad_frames_, errors_);
  }

 private:
  std::unique_ptr<drv::OpenNi2Camera> cam_;
  drv::FrameAssembler assembler_;
  CameraSourceOptions options_;
  uint64_t seq_ = 0, bad_frames_ = 0, errors_ = 0;
};
#endif

[[maybe_unused]] Error notBuilt(const char* what, const char* package) {
  return Error{fmt::format("{}: this hxmap was built without it (apt install {}, then configure and build again)", what,
                           package)};
}

}  // namespace

Expected<CameraSpec> parseCameraSpec(const std::string& spec) {
  auto bad = [&](const std::string& why) {
    return Error{fmt::format("camera '{}': {}; the forms are {}", spec, why, kSpecForms)};
  };
  CameraSpec s;
  if (spec.rfind("v4l2:", 0) == 0) {
    const std::string rest = spec.substr(5);
    const size_t plus = rest.find('+');
    if (plus == std::string::npos) return bad("a V4L2 camera needs a color and a depth device");
    s.kind = CameraSpec::Kind::kV4l2Pair;
    s.color = rest.substr(0, plus);
    s.depth = rest.substr(plus + 1);
    if (s.color.empty() || s.depth.empty()) return bad("empty device path");
    if (s.color == s.depth) return bad("the color and depth devices are the same node");
    return s;
  }
  if (spec == "openni2" || spec.rfind("openni2:", 0) == 0) {
    s.kind = CameraSpec::Kind::kOpenNi2;
    s.color = spec.size() > 8 ? spec.substr(8) : std::string();
    return s;
  }
  if (spec.rfind("libcamera", 0) == 0) {
    const size_t plus = spec.find("+v4l2:");
    if (plus == std::string::npos) return bad("a libcamera color camera needs a depth camera: +v4l2:DEPTH_DEV");
    const std::string head = spec.substr(0, plus);
    if (head != "libcamera" && head.rfind("libcamera:", 0) != 0) return bad("unknown camera kind");
    s.kind = CameraSpec::Kind::kLibcameraV4l2;
    s.color = head.size() > 10 ? head.substr(10) : std::string();
    s.depth = spec.substr(plus + 6);
    if (s.depth.empty()) return bad("empty depth device path");
    return s;
  }
  return bad("unknown camera kind");
}

std::string describe(const CameraSpec& spec) {
  switch (spec.kind) {
    case CameraSpec::Kind::kV4l2Pair: return fmt::format("V4L2 color {} + depth {}", spec.color, spec.depth);
    case CameraSpec::Kind::kOpenNi2:
      return fmt::format("OpenNI2 {}", spec.color.empty() ? std::string("(first device)") : spec.color);
    case CameraSpec::Kind::kLibcameraV4l2:
      return fmt::format("libcamera {} + V4L2 depth {}", spec.color.empty() ? std::string("(first camera)") : spec.color,
                         spec.depth);
  }
  return "?";
}

#ifdef HXMAP_HAVE_V4L2
Expected<std::unique_ptr<CameraSource>> openCameraSource(const CameraSpec& spec, const CameraSourceOptions& options,
                                                         std::shared_ptr<drv::DeviceIo> color_io,
                                                         std::shared_ptr<drv::DeviceIo> depth_io) {
#else
Expected<std::unique_ptr<CameraSource>> openCameraSource(const CameraSpec& spec, const CameraSourceOptions& options) {
#endif
  if (options.lost_timeout_s <= 0 || options.ring_capacity < 1) {
    return Error{"camera: lost_timeout_s and ring_capacity must be positive"};
  }
  const drv::RigCalibration& cal = options.calibration;
  switch (spec.kind) {
    case CameraSpec::Kind::kV4l2Pair: {
#ifdef HXMAP_HAVE_V4L2
      auto assembler = drv::FrameAssembler::create(cal);
      if (!assembler) return Error{assembler.message()};
      auto color = openV4l2(spec.color, false, cal.color.width, cal.color.height, options, std::move(color_io));
      if (!color) return Error{color.message()};
      auto depth = openV4l2(spec.depth, true, cal.depth.width, cal.depth.height, options, std::move(depth_io));
      if (!depth) return Error{depth.message()};
      std::shared_ptr<drv::V4l2Camera> c = *color, d = *depth;
      auto grab_color = [c]() -> Expected<drv::ColorImage> {
        auto f = c->grab(0.5);
        if (!f) return Error{f.message()};
        return drv::ColorImage{f->stamp_ns, f->sequence, std::move(f->image)};
      };
      // Driver counters are read after the grabbers stopped or as a rough
      // live figure (plain integers written by one thread).
      auto stats = [c, d] { return v4l2StatsText(*c) + "; " + v4l2StatsText(*d); };
      return std::unique_ptr<CameraSource>(std::make_unique<TwoStreamSource>(
          describe(spec), options, std::move(*assembler), grab_color, spec.color, v4l2DepthGrab(d), spec.depth, stats));
#else
      return notBuilt("v4l2 cameras", "libv4l-dev");
#endif
    }
    case CameraSpec::Kind::kOpenNi2: {
#ifdef HXMAP_HAVE_OPENNI2
      drv::OpenNi2Options oo;
      oo.uri = spec.color;
      oo.width = cal.color.width;
      oo.height = cal.color.height;
      oo.fps = static_cast<int>(std::lround(options.fps));
      oo.registration = true;
      oo.max_gap_s = options.max_sync_gap_s;
      auto cam = drv::OpenNi2Camera::open(oo);
      if (!cam) return Error{cam.message()};
      // The device's intrinsics; extrinsics and scale from the rig: section
      // unless the device registers depth to color itself.
      drv::RigCalibration dc = (*cam)->calibration();
      if (!dc.registered) dc.T_color_depth = cal.T_color_depth;
      dc.max_depth_m = cal.max_depth_m;
      auto assembler = drv::FrameAssembler::create(dc);
      if (!assembler) return Error{fmt::format("{}: {}", (*cam)->name(), assembler.message())};
      return std::unique_ptr<CameraSource>(std::make_unique<OpenNi2Source>(std::move(*cam), std::move(*assembler), options));
#else
      return notBuilt("openni2 cameras", "libopenni2-dev");
#endif
    }
    case CameraSpec::Kind::kLibcameraV4l2: {
#if defined(HXMAP_HAVE_LIBCAMERA) && defined(HXMAP_HAVE_V4L2)
      auto assembler = drv::FrameAssembler::create(cal);
      if (!assembler) return Error{assembler.message()};
      drv::LibcameraOptions lo;
      lo.camera_id = spec.color;
      lo.width = cal.color.width;
      lo.height = cal.color.height;
      auto lc = drv::LibcameraCamera::open(lo);
      if (!lc) return Error{lc.message()};
      std::shared_ptr<drv::LibcameraCamera> c = std::move(*lc);
      if (c->width() != cal.color.width || c->height() != cal.color.height) {
        return Error{fmt::format("libcamera {}: the camera streams {}x{}, but rig.color_width/color_height say {}x{}",
                                 c->id(), c->width(), c->height(), cal.color.width, cal.color.height)};
      }
      auto depth = openV4l2(spec.depth, true, cal.depth.width, cal.depth.height, options, std::move(depth_io));
      if (!depth) return Error{depth.message()};
      std::shared_ptr<drv::V4l2Camera> d = *depth;
      auto grab_color = [c]() -> Expected<drv::ColorImage> {
        auto f = c->grab(0.5);
        if (!f) return Error{f.message()};
        return drv::ColorImage{f->stamp_ns, f->sequence, std::move(f->rgb)};
      };
      auto stats = [c, d] {
        const drv::LibcameraStats s = c->stats();
        return fmt::format("libcamera {}: {} lost by the driver, {} failed requests; ", c->id(), s.lost_by_driver,
                           s.failed) +
               v4l2StatsText(*d);
      };
      const std::string color_name = "libcamera " + c->id();
      return std::unique_ptr<CameraSource>(std::make_unique<TwoStreamSource>(
          describe(spec), options, std::move(*assembler), grab_color, color_name, v4l2DepthGrab(d), spec.depth, stats));
#else
      return notBuilt("libcamera cameras", "libcamera-dev libv4l-dev");
#endif
    }
  }
  return Error{"camera: unknown kind"};
}

}  // namespace hxmap::rt
