// A color stream from a libcamera camera (CSI sensors on robot computers;
// USB cameras show up too), for pairing with a separate depth sensor.
//
// open(): starts the camera manager, picks the camera (by id, or the first),
// acquires it, configures one video stream at the wanted size in a packed
// RGB or YUYV format, maps the allocated buffers and queues one request per
// buffer. Completed requests arrive on libcamera's thread; they are handed
// to grab() through a small mutex-guarded queue (the one lock in a driver
// thread, never on the frontend's path). Stamps are the sensor's
// (CLOCK_MONOTONIC, ns). A camera that is unplugged cancels its requests
// and grab() returns an Error naming it.
//
// Thread safety: one thread calls grab().
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "hxmap/core/expected.hpp"

namespace hxmap::drv {

struct LibcameraOptions {
  std::string camera_id;  ///< empty = the first camera
  int width = 640, height = 480;
  int buffers = 4;
};

struct LibcameraFrame {
  int64_t stamp_ns = 0;
  uint64_t sequence = 0;
  cv::Mat rgb;  ///< CV_8UC3 R,G,B
};

struct LibcameraStats {
  uint64_t frames = 0, lost_by_driver = 0, failed = 0;
};

class LibcameraCamera {
 public:
  static Expected<std::unique_ptr<LibcameraCamera>> open(const LibcameraOptions& options);
  ~LibcameraCamera();
  LibcameraCamera(const LibcameraCamera&) = delete;
  LibcameraCamera& operator=(const LibcameraCamera&) = delete;

  Expected<LibcameraFrame> grab(double timeout_s = 1.0);
  const std::string& id() const;
  int width() const;
  int height() const;
  LibcameraStats stats() const;

 private:
  struct Impl;
  LibcameraCamera();
  std::unique_ptr<Impl> impl_;
};

}  // namespace hxmap::drv
