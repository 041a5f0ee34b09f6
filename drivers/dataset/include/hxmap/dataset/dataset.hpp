// Datasets on disk as a stream of RgbdFrame plus ground truth when present.
//
// Supported layouts:
//  - TUM RGB-D: rgb.txt, depth.txt (associated by nearest timestamp, at most
//    0.02 s apart, as the benchmark's associate.py), optional
//    groundtruth.txt, depth PNG uint16 at 5000 per meter; intrinsics from
//    calibration.yaml in the folder, else the fr1/fr2/fr3 preset named by the
//    folder ("freiburg1" ...), else the caller's camera.
//  - Replica in the NICE-SLAM layout: results/frameNNNNNN.jpg,
//    results/depthNNNNNN.png, traj.txt (4x4 camera-to-world per line),
//    cam_params.json (or ../cam_params.json) with fx fy cx cy w h scale.
// The built-in synthetic scenes write the TUM layout with calibration.yaml.
//
// Thread safety: a Dataset is immutable after open(); load() may be called
// concurrently for different frames.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "hxmap/core/expected.hpp"
#include "hxmap/core/frame.hpp"
#include "hxmap/geometry/camera.hpp"

namespace hxmap::drv {

struct DatasetOptions {
  /// Skip bad list lines and unreadable frames (counted and logged) instead of
  /// failing on the first one.
  bool skip_bad = false;
  /// Undistort images when the camera has distortion (frames downstream are
  /// always distortion free).
  bool undistort = true;
  double max_association_s = 0.02;
  /// Used when the dataset carries no intrinsics of its own; `force_camera`
  /// overrides the dataset's own.
  std::optional<alg::PinholeCamera> camera;
  bool force_camera = false;
  std::string camera_origin = "configuration (camera section)";  ///< where `camera` came from, for the log
  /// Depth pixels per meter; 0 means the dataset's own (TUM 5000, Replica 6553.5).
  double depth_scale = 0.0;
};

enum class DatasetKind { kTum, kReplica };

class Dataset {
 public:
  /// Detects the layout of `dir` and reads its lists (not the images).
  static Expected<std::unique_ptr<Dataset>> open(const std::string& dir, const DatasetOptions& options = {});

  DatasetKind kind() const { return kind_; }
  const std::string& dir() const { return dir_; }
  size_t size() const { return frames_.size(); }
  const alg::PinholeCamera& camera() const { return camera_; }
  std::string cameraSource() const { return camera_source_; }
  double depthScale() const { return depth_scale_; }
  /// The sensor returns no depth where |cos(incidence)| is below this (0:
  /// unknown). Known for synthetic sequences (calibration.yaml
  /// sensor_grazing_cos); mesh evaluation counts ground truth seen only at
  /// such angles as never observed.
  double sensorGrazingCos() const { return sensor_grazing_cos_; }
  /// Ground truth camera-to-world poses (own stamps), empty when absent.
  const Trajectory& groundTruth() const { return ground_truth_; }
  /// Messages of list lines skipped at open() (skip_bad only).
  const std::vector<std::string>& skippedAtOpen() const { return skipped_; }
  int64_t stamp(size_t i) const { return frames_[i].stamp_ns; }

  /// Reads and validates frame i (0 <= i < size()). Errors name the file and
  /// the list line that referenced it.
  Expected<RgbdFrame> load(size_t i) const;
  /// Every frame in order (benchmarks, tests); the first unreadable one is
  /// the error.
  Expected<std::vector<RgbdFrame>> loadAll() const;

 private:
  struct FrameFiles {
    int64_t stamp_ns;
    std::string rgb_path, depth_path;  ///< absolute
    std::string rgb_ref, depth_ref;    ///< "rgb.txt:12" or the file name
    int64_t depth_stamp_ns = 0;        ///< the associated depth image's own stamp
  };
  Dataset() = default;
  static Status openTum(Dataset& d, const DatasetOptions& options);
  static Status openReplica(Dataset& d, const DatasetOptions& options);
  Status finishCamera(const DatasetOptions& options);

  DatasetKind kind_ = DatasetKind::kTum;
  std::string dir_;
  std::vector<FrameFiles> frames_;
  alg::PinholeCamera camera_;
  std::string camera_source_;
  double depth_scale_ = 5000.0;
  double sensor_grazing_cos_ = 0.0;
  Trajectory ground_truth_;
  std::vector<std::string> skipped_;
  cv::Mat undistort_x_, undistort_y_;  ///< CV_32F maps, empty when not needed
};

/// The published TUM RGB-D intrinsics of freiburg 1, 2 or 3.
alg::PinholeCamera tumCameraPreset(int freiburg);
/// By name: "fr1", "fr2", "fr3" (tumCameraPreset) or "kinect" (525, 525,
/// 319.5, 239.5 at 640x480, no distortion: the ROS default).
alg::PinholeCamera cameraPreset(const std::string& name);

/// A dataset's own camera: intrinsics (with distortion), raw depth units
/// per meter, and the depth sensor's grazing-angle limit.
struct Calibration {
  alg::PinholeCamera camera;
  double depth_scale = 5000.0;
  double sensor_grazing_cos = 0.0;
};
/// calibration.yaml (fx fy cx cy width height, optional distortion,
/// depth_scale, sensor_grazing_cos), every value checked like the
/// configuration's: all problems reported together, each with `path`, line
/// and key; sizes up to 8192 pixels.
Expected<Calibration> parseCalibrationYaml(const std::string& text, const std::string& path);
/// Replica's cam_params.json (camera.fx fy cx cy w h scale), checked alike.
Expected<Calibration> parseReplicaCamParams(const std::string& text, const std::string& path);

/// Reads a whole file; error names the path.
Expected<std::string> readTextFile(const std::string& path);

/// Decodes an image file with integrity checks: exists, not truncated (PNG
/// IEND / JPEG EOI present), decodes, expected type. `depth16` asks for a
/// single-channel 16-bit image, otherwise 8-bit color (returned as RGB).
/// `ref` is how the caller names the file in messages ("rgb.txt:12").
Expected<cv::Mat> readImage(const std::string& path, const std::string& ref, bool depth16);
/// The same checks and decoding on an image file's bytes (`path` names it
/// in messages). Images above OPENCV_IO_MAX_IMAGE_PIXELS (hxmap sets 8192²)
/// are refused by the decoder.
Expected<cv::Mat> decodeImage(const std::string& bytes, const std::string& path, const std::string& ref, bool depth16);

}  // namespace hxmap::drv
