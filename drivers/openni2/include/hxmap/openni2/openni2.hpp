// OpenNI2 RGB-D cameras (Kinect, Xtion, Astra) and .oni recordings.
//
// open(): initializes OpenNI2 (once per process), opens the device (the
// first one found, one by URI, or a recording when the URI is a .oni file),
// starts a color and a depth stream at the wanted mode (the nearest the
// device lists), turns on the device's depth-to-color registration and
// frame sync when it offers them, and derives the pinhole intrinsics from
// the streams' fields of view. A recording plays as fast as it is read
// (or at its recorded rate with `realtime_playback`), once.
// grab(): waits for frames of both streams and pairs them by time through
// StreamSync (max_gap_s); returns a pair ready for FrameAssembler.
// Devices that vanish are an Error naming the device (OpenNI2 reports it
// as a stream error or timeout).
//
// Thread safety: one thread per camera.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/sync/sync.hpp"

namespace hxmap::drv {

struct OpenNi2Options {
  std::string uri;          ///< empty = the first device; a path ending in .oni = a recording
  int width = 640, height = 480;
  int fps = 30;
  bool registration = true; ///< use the device's depth-to-color registration when offered
  bool realtime_playback = false;
  double max_gap_s = 0.02;
};

struct OpenNi2Stats {
  uint64_t color_frames = 0, depth_frames = 0;
  SyncStats sync;
};

class OpenNi2Camera {
 public:
  static Expected<std::unique_ptr<OpenNi2Camera>> open(const OpenNi2Options& options);
  ~OpenNi2Camera();
  OpenNi2Camera(const OpenNi2Camera&) = delete;
  OpenNi2Camera& operator=(const OpenNi2Camera&) = delete;

  /// The next color + depth pair. Errors: the device stopped delivering
  /// (vanished) for timeout_s, or a recording ended ("end of recording").
  Expected<SyncedPair> grab(double timeout_s = 2.0);

  /// Calibration from the device: color and depth intrinsics from the fields
  /// of view, depth scale from the pixel format, registered when the device
  /// registers depth to color in hardware (else identity extrinsics: give
  /// calibrated ones in the configuration).
  const RigCalibration& calibration() const { return calibration_; }
  bool isRecording() const { return recording_; }
  /// Frames in a recording (0 for a live device).
  int recordingFrames() const { return recording_frames_; }
  const std::string& name() const { return name_; }
  OpenNi2Stats stats() const;

 private:
  struct Impl;
  explicit OpenNi2Camera(const OpenNi2Options& options);
  OpenNi2Options options_;
  std::unique_ptr<Impl> impl_;
  RigCalibration calibration_;
  bool recording_ = false;
  int recording_frames_ = 0;
  std::string name_;
};

}  // namespace hxmap::drv
