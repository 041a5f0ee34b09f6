// Live RGB-D cameras as a FrameSource for the real-time runner.
//
// A camera is named by a spec string:
//   v4l2:COLOR_DEV+DEPTH_DEV      two UVC nodes (e.g. a RealSense's color and
//                                 Z16 depth nodes): /dev/video4+/dev/video2
//   openni2[:URI]                 an OpenNI2 device (the first one, or by URI),
//                                 or a .oni recording: openni2:walk.oni
//   libcamera[:ID]+v4l2:DEPTH_DEV a CSI color camera through libcamera with a
//                                 separate UVC depth camera
//
// Threads: a stream that has its own device (v4l2 and libcamera color, v4l2
// depth) is read by its own grabber thread (hx-grab-color, hx-grab-depth),
// which blocks in the driver and hands each decoded image to the sensor
// thread through a bounded SPSC ring (full: the image is dropped and
// counted). The sensor thread (the runner's hx-sensor, inside next()) pairs
// the streams by time (StreamSync), registers depth into the color camera
// (FrameAssembler, with the rig: calibration) and returns the frame. OpenNI2
// pairs its streams itself and is read by next() directly.
//
// Device loss: the V4L2 driver reopens an unplugged device by itself (the
// gap is counted in its sequence numbers); a stream that delivers nothing
// for lost_timeout_s ends the source with an Error naming the device, so
// the run stops cleanly and writes what it mapped.
#pragma once

#include <memory>
#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/realtime/realtime.hpp"
#include "hxmap/sync/sync.hpp"

#ifdef HXMAP_HAVE_V4L2
#include "hxmap/v4l2/camera.hpp"
#endif

namespace hxmap::rt {

struct CameraSpec {
  enum class Kind { kV4l2Pair, kOpenNi2, kLibcameraV4l2 };
  Kind kind = Kind::kV4l2Pair;
  std::string color;  ///< v4l2 color device, OpenNI2 URI (may be empty) or libcamera id (may be empty)
  std::string depth;  ///< v4l2 depth device (empty for OpenNI2)
};

/// Parses a spec (see above); the error shows the accepted forms.
Expected<CameraSpec> parseCameraSpec(const std::string& spec);
std::string describe(const CameraSpec& spec);

struct CameraSourceOptions {
  drv::RigCalibration calibration;  ///< the rig: section (OpenNI2 takes the device's own when it registers)
  double max_sync_gap_s = 0.02;
  double fps = 30;                  ///< asked of the devices; the scheduler plans for it
  double reconnect_timeout_s = 5;   ///< V4L2: how long an unplugged device is reopened
  double lost_timeout_s = 10;       ///< a stream silent this long ends the source
  int ring_capacity = 4;            ///< images waiting per stream
};

/// A live camera. Not copyable; destruction stops the grabber threads and
/// the devices.
class CameraSource : public FrameSource {
 public:
  ~CameraSource() override = default;
  /// The camera of the frames delivered (the color camera, undistorted).
  virtual const alg::PinholeCamera& camera() const = 0;
  virtual std::string name() const = 0;
};

#ifdef HXMAP_HAVE_V4L2
/// Opens the devices and starts streaming (the grabbers start on the first
/// next()). `io` stands in for the system calls of V4L2 devices (tests).
Expected<std::unique_ptr<CameraSource>> openCameraSource(const CameraSpec& spec, const CameraSourceOptions& options,
                                                         std::shared_ptr<drv::DeviceIo> color_io = drv::systemIo(),
                                                         std::shared_ptr<drv::DeviceIo> depth_io = drv::systemIo());
#else
Expected<std::unique_ptr<CameraSource>> openCameraSource(const CameraSpec& spec, const CameraSourceOptions& options);
#endif

}  // namespace hxmap::rt
