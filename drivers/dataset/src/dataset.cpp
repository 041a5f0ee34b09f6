#include "hxmap/dataset/dataset.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <sstream>
#include <tuple>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "hxmap/dataset/parsers.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/jpeg/jpeg.hpp"

namespace fs = std::filesystem;

namespace hxmap::drv {

alg::PinholeCamera cameraPreset(const std::string& name) {
  if (name == "fr1") return tumCameraPreset(1);
  if (name == "fr2") return tumCameraPreset(2);
  if (name == "fr3") return tumCameraPreset(3);
  return {525.0, 525.0, 319.5, 239.5, 640, 480, {0, 0, 0, 0, 0}};  // kinect: the ROS default
}

alg::PinholeCamera tumCameraPreset(int freiburg) {
  alg::PinholeCamera c;
  c.width = 640;
  c.height = 480;
  switch (freiburg) {
    case 1:
      c.fx = 517.3, c.fy = 516.5, c.cx = 318.6, c.cy = 255.3;
      c.distortion = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
      break;
    case 2:
      c.fx = 520.9, c.fy = 521.0, c.cx = 325.1, c.cy = 249.7;
      c.distortion = {0.2312, -0.7849, -0.0033, -0.0001, 0.9172};
      break;
    default:  // fr3 images are already undistorted
      c.fx = 535.4, c.fy = 539.2, c.cx = 320.1, c.cy = 247.6;
      break;
  }
  return c;
}

Expected<std::string> readTextFile(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return Error{path + ": file does not exist"};
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{path + ": cannot open for reading"};
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

namespace {

std::string describeType(const cv::Mat& m) {
  const int depth = m.depth();
  const char* bits = depth == CV_8U ? "8-bit" : depth == CV_16U ? "16-bit" : depth == CV_32F ? "32-bit float" : "other";
  return fmt::format("{} {}-channel", bits, m.channels());
}

}  // namespace

Expected<cv::Mat> readImage(const std::string& path, const std::string& ref, bool depth16) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return Error{fmt::format("{}: listed file {} does not exist", ref, path)};
  auto bytes = readTextFile(path);
  if (!bytes) return Error{fmt::format("{}: {}", ref, bytes.message())};
  return decodeImage(*bytes, path, ref, depth16);
}

Expected<cv::Mat> decodeImage(const std::string& b, const std::string& path, const std::string& ref, bool depth16) {
  if (b.size() > static_cast<size_t>(std::numeric_limits<int>::max())) {
    return Error{fmt::format("{}: {} is larger than 2 GiB", ref, path)};
  }
  const bool is_png = b.size() >= 8 && b.compare(0, 8, "\x89PNG\r\n\x1a\n") == 0;
  const bool is_jpeg = b.size() >= 3 && static_cast<uint8_t>(b[0]) == 0xFF && static_cast<uint8_t>(b[1]) == 0xD8;
  if (!is_png && !is_jpeg) return Error{fmt::format("{}: {} is not a PNG or JPEG image", ref, path)};
  if (is_png && (b.size() < 20 || b.find("IEND", b.size() - 16) == std::string::npos)) {
    return Error{fmt::format("{}: {} is a truncated PNG (no IEND chunk)", ref, path)};
  }
  const auto* bytes = reinterpret_cast<const uint8_t*>(b.data());
  if (is_jpeg && !drv::isWholeJpeg(bytes, b.size(), 64))
    return Error{fmt::format("{}: {} is a truncated JPEG (no EOI marker)", ref, path)};
  if (is_jpeg) {
    if (depth16) {
      return Error{fmt::format("{}: depth image {} is a JPEG (8-bit), expected 16-bit single-channel", ref, path)};
    }
    auto rgb = drv::decodeJpegRgb(bytes, b.size());
    if (!rgb) return Error{fmt::format("{}: {} {}", ref, path, rgb.message())};
    return rgb;
  }
  cv::Mat img;
  try {
    const cv::Mat buf(1, static_cast<int>(b.size()), CV_8UC1, const_cast<char*>(b.data()));
    img = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    return Error{fmt::format("{}: {} could not be decoded: {}", ref, path, e.what())};
  }
  if (img.empty()) return Error{fmt::format("{}: {} is corrupt (the decoder rejected it)", ref, path)};
  if (depth16) {
    if (img.type() != CV_16UC1) {
      return Error{
          fmt::format("{}: depth image {} is {}, expected 16-bit single-channel", ref, path, describeType(img))};
    }
    return img;
  }
  if (img.depth() != CV_8U || (img.channels() != 3 && img.channels() != 4 && img.channels() != 1)) {
    return Error{fmt::format("{}: color image {} is {}, expected 8-bit color", ref, path, describeType(img))};
  }
  cv::Mat rgb;
  if (img.channels() == 1) {
    cv::cvtColor(img, rgb, cv::COLOR_GRAY2RGB);
  } else if (img.channels() == 4) {
    cv::cvtColor(img, rgb, cv::COLOR_BGRA2RGB);
  } else {
    cv::cvtColor(img, rgb, cv::COLOR_BGR2RGB);
  }
  return rgb;
}

Expected<std::unique_ptr<Dataset>> Dataset::open(const std::string& dir, const DatasetOptions& options) {
  std::unique_ptr<Dataset> d(new Dataset());
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return Error{dir + ": dataset folder does not exist"};
  d->dir_ = fs::absolute(dir).lexically_normal().string();
  Status status;
  if (fs::exists(fs::path(dir) / "rgb.txt") || fs::exists(fs::path(dir) / "depth.txt")) {
    d->kind_ = DatasetKind::kTum;
    status = openTum(*d, options);
  } else if (fs::is_directory(fs::path(dir) / "results") || fs::exists(fs::path(dir) / "traj.txt")) {
    d->kind_ = DatasetKind::kReplica;
    status = openReplica(*d, options);
  } else {
    return Error{dir +
                 ": not a dataset folder: expected rgb.txt + depth.txt (TUM layout) or results/ + traj.txt "
                 "(Replica NICE-SLAM layout)"};
  }
  if (!status) return Error{status.message()};
  if (options.depth_scale > 0) d->depth_scale_ = options.depth_scale;
  if (auto s = d->finishCamera(options); !s) return Error{s.message()};
  for (const auto& m : d->skipped_) spdlog::warn("skipped: {}", m);
  return d;
}

namespace {
constexpr int kMaxSide = 8192;

// The names a calibration file gives the intrinsics.
struct IntrinsicKeys {
  const char *fx, *fy, *cx, *cy, *width, *height, *depth_scale;
};

// Focal lengths, image size, principal point and depth scale checked
// alike for every calibration file: each problem with where() of its key.
void checkIntrinsics(const IntrinsicKeys& k, const std::function<std::string(const char*)>& where, double width,
                     double height, Calibration& c, std::vector<std::string>& problems) {
  alg::PinholeCamera& cam = c.camera;
  for (const auto& [key, value] : {std::pair{k.fx, cam.fx}, {k.fy, cam.fy}}) {
    if (!(std::isfinite(value) && value > 0)) {
      problems.push_back(fmt::format("{} must be a positive focal length in pixels, got {}", where(key), value));
    }
  }
  for (const auto& [key, value] : {std::pair{k.width, width}, {k.height, height}}) {
    if (!(value >= 1 && value <= kMaxSide && value == std::floor(value))) {
      problems.push_back(
          fmt::format("{} must be a whole number of pixels in [1, {}], got {}", where(key), kMaxSide, value));
    }
  }
  cam.width = width >= 1 && width <= kMaxSide ? static_cast<int>(width) : 1;
  cam.height = height >= 1 && height <= kMaxSide ? static_cast<int>(height) : 1;
  for (const auto& [key, value, side] : {std::tuple{k.cx, cam.cx, width}, {k.cy, cam.cy, height}}) {
    if (!(std::isfinite(value) && value >= 0 && value < side)) {
      problems.push_back(fmt::format("{} must lie inside the image, [0, {}), got {}", where(key), side, value));
    }
  }
  if (!(std::isfinite(c.depth_scale) && c.depth_scale > 0)) {
    problems.push_back(
        fmt::format("{} must be positive (raw depth units per meter), got {}", where(k.depth_scale), c.depth_scale));
  }
}
// Numbers of one calibration file's map, each problem with the file, the
// line and the key (under `prefix`, e.g. "camera.").
class KeyReader {
 public:
  KeyReader(YAML::Node map, std::string path, std::string prefix, std::vector<std::string>& problems)
      : map_(std::move(map)), path_(std::move(path)), prefix_(std::move(prefix)), problems_(problems) {}
  std::string where(const char* key) const {
    const YAML::Node v = map_[key];
    return v ? fmt::format("{}:{}: {}{}", path_, v.Mark().line + 1, prefix_, key)
             : fmt::format("{}: {}{}", path_, prefix_, key);
  }
  double number(const char* key, bool required, double fallback) {
    const YAML::Node v = map_[key];
    if (!v) {
      if (required) problems_.push_back(fmt::format("{}: missing key '{}{}'", path_, prefix_, key));
      return fallback;
    }
    try {
      return v.as<double>();
    } catch (const YAML::Exception&) {
      problems_.push_back(fmt::format("{} must be a number", where(key)));
      return fallback;
    }
  }
  std::vector<std::string>& problems() { return problems_; }

 private:
  const YAML::Node map_;
  std::string path_, prefix_;
  std::vector<std::string>& problems_;
};

// The intrinsics, image size and depth scale under `k`'s names, read and
// checked alike for every calibration file.
void readIntrinsics(KeyReader& r, const IntrinsicKeys& k, double default_scale, Calibration& c) {
  alg::PinholeCamera& cam = c.camera;
  cam.fx = r.number(k.fx, true, 1.0);
  cam.fy = r.number(k.fy, true, 1.0);
  cam.cx = r.number(k.cx, true, 0.0);
  cam.cy = r.number(k.cy, true, 0.0);
  const double width = r.number(k.width, true, 1.0), height = r.number(k.height, true, 1.0);
  c.depth_scale = r.number(k.depth_scale, false, default_scale);
  checkIntrinsics(
      k, [&](const char* key) { return r.where(key); }, width, height, c, r.problems());
}
}  // namespace

Expected<Calibration> parseCalibrationYaml(const std::string& text, const std::string& path) {
  static const char* const kKeys[] = {
      "fx", "fy", "cx", "cy", "width", "height", "distortion", "depth_scale", "sensor_grazing_cos"};
  YAML::Node n;
  try {
    n = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    return Error{fmt::format("{}: {}", path, e.what())};
  }
  if (!n.IsMap()) return Error{path + ": expected a map of keys fx fy cx cy width height [distortion] [depth_scale]"};
  std::vector<std::string> problems;
  auto where = [&](const YAML::Node& node, const std::string& key) {
    return fmt::format("{}:{}: {}", path, node.Mark().line + 1, key);
  };
  for (const auto& kv : n) {
    const std::string key = kv.first.as<std::string>("");
    if (std::find_if(std::begin(kKeys), std::end(kKeys), [&](const char* k) { return key == k; }) == std::end(kKeys)) {
      problems.push_back(fmt::format("{} is not a known key (known: fx fy cx cy width height distortion depth_scale "
                                     "sensor_grazing_cos)",
                                     where(kv.first, "'" + key + "'")));
    }
  }
  KeyReader reader(n, path, "", problems);
  Calibration c;
  alg::PinholeCamera& cam = c.camera;
  readIntrinsics(reader, {"fx", "fy", "cx", "cy", "width", "height", "depth_scale"}, 5000.0, c);
  c.sensor_grazing_cos = reader.number("sensor_grazing_cos", false, 0.0);
  if (!(c.sensor_grazing_cos >= 0 && c.sensor_grazing_cos < 1)) {
    problems.push_back(fmt::format("{} must lie in [0, 1), got {}", where(n["sensor_grazing_cos"], "sensor_grazing_cos"),
                                   c.sensor_grazing_cos));
  }
  if (const YAML::Node d = n["distortion"]) {
    std::vector<double> v;
    try {
      v = d.as<std::vector<double>>();
    } catch (const YAML::Exception&) {
    }
    if (v.size() != 5) {
      problems.push_back(fmt::format("{} needs 5 numbers k1 k2 p1 p2 k3", where(d, "distortion")));
    } else if (!std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); })) {
      problems.push_back(fmt::format("{} must be finite", where(d, "distortion")));
    } else {
      std::copy(v.begin(), v.end(), cam.distortion.begin());
    }
  }
  if (!problems.empty()) {
    return Error{fmt::format("{} problem(s) in the camera calibration:\n{}", problems.size(),
                             fmt::join(problems, "\n"))};
  }
  return c;
}

Expected<Calibration> parseReplicaCamParams(const std::string& text, const std::string& path) {
  YAML::Node n;
  try {
    n = YAML::Load(text);  // JSON is valid YAML
  } catch (const YAML::Exception& e) {
    return Error{fmt::format("{}: {}", path, e.what())};
  }
  const YAML::Node c = n.IsMap() && n["camera"] ? n["camera"] : n;
  if (!c.IsMap()) return Error{path + ": expected an object with camera.fx fy cx cy w h [scale]"};
  std::vector<std::string> problems;
  KeyReader reader(c, path, "camera.", problems);
  Calibration out;
  readIntrinsics(reader, {"fx", "fy", "cx", "cy", "w", "h", "scale"}, 6553.5, out);
  if (!problems.empty()) {
    return Error{
        fmt::format("{} problem(s) in the camera parameters:\n{}", problems.size(), fmt::join(problems, "\n"))};
  }
  return out;
}

Status Dataset::openTum(Dataset& d, const DatasetOptions& options) {
  const fs::path dir(d.dir_);
  ParseOptions po{options.skip_bad};
  auto parse_list = [&](const char* name) -> Expected<ParsedList> {
    const std::string path = (dir / name).string();
    auto text = readTextFile(path);
    if (!text) return Error{text.message() + " (a TUM dataset needs rgb.txt and depth.txt)"};
    return parseTumList(*text, path, po);
  };
  auto rgb = parse_list("rgb.txt");
  if (!rgb) return Error{rgb.message()};
  auto depth = parse_list("depth.txt");
  if (!depth) return Error{depth.message()};
  d.skipped_.insert(d.skipped_.end(), rgb->skipped.begin(), rgb->skipped.end());
  d.skipped_.insert(d.skipped_.end(), depth->skipped.begin(), depth->skipped.end());

  std::vector<int64_t> rs, ds;
  for (const auto& e : rgb->entries) rs.push_back(e.stamp_ns);
  for (const auto& e : depth->entries) ds.push_back(e.stamp_ns);
  alg::AssociationParams ap;
  ap.max_difference_ns = static_cast<int64_t>(options.max_association_s * 1e9);
  const auto pairs = alg::associateStamps(rs, ds, ap);
  if (pairs.empty()) {
    return Error{fmt::format("{}: no color frame in rgb.txt has a depth frame in depth.txt within {} s", d.dir_,
                             options.max_association_s)};
  }
  const std::string rgb_list = (dir / "rgb.txt").string(), depth_list = (dir / "depth.txt").string();
  for (const auto& [i, j] : pairs) {
    const auto& re = rgb->entries[i];
    const auto& de = depth->entries[j];
    d.frames_.push_back({re.stamp_ns, (dir / re.path).string(), (dir / de.path).string(),
                         fmt::format("{}:{}", rgb_list, re.line), fmt::format("{}:{}", depth_list, de.line),
                         de.stamp_ns});
  }
  const fs::path gt = dir / "groundtruth.txt";
  if (fs::exists(gt)) {
    auto text = readTextFile(gt.string());
    if (!text) return Error{text.message()};
    auto traj = parseTumTrajectory(*text, gt.string(), po);
    if (!traj) return Error{traj.message()};
    d.skipped_.insert(d.skipped_.end(), traj->skipped.begin(), traj->skipped.end());
    d.ground_truth_ = std::move(traj->poses);
    std::stable_sort(d.ground_truth_.begin(), d.ground_truth_.end(),
                     [](const StampedPose& a, const StampedPose& b) { return a.stamp_ns < b.stamp_ns; });
  }
  d.depth_scale_ = 5000.0;
  const fs::path calib = dir / "calibration.yaml";
  const std::string name = dir.filename().string();
  if (fs::exists(calib)) {
    auto text = readTextFile(calib.string());
    if (!text) return text.error();
    auto c = parseCalibrationYaml(*text, calib.string());
    if (!c) return Error{c.message()};
    d.camera_ = c->camera;
    d.camera_source_ = calib.string();
    d.depth_scale_ = c->depth_scale;
    d.sensor_grazing_cos_ = c->sensor_grazing_cos;
  } else {
    for (int fr = 1; fr <= 3; ++fr) {
      if (name.find(fmt::format("freiburg{}", fr)) != std::string::npos) {
        d.camera_ = tumCameraPreset(fr);
        d.camera_source_ = fmt::format("TUM freiburg{} preset (from the folder name)", fr);
      }
    }
  }
  return Status::ok();
}

namespace {
// "frame000012.jpg" with prefix "frame": true and number 12.
bool numberedName(const std::string& name, const std::string& prefix, std::initializer_list<const char*> suffixes,
                  long& number) {
  if (name.rfind(prefix, 0) != 0) return false;
  for (const char* suffix : suffixes) {
    const std::string sfx(suffix);
    if (name.size() <= prefix.size() + sfx.size() || name.compare(name.size() - sfx.size(), sfx.size(), sfx) != 0) {
      continue;
    }
    const std::string digits = name.substr(prefix.size(), name.size() - prefix.size() - sfx.size());
    if (digits.empty() || digits.size() > 9 || digits.find_first_not_of("0123456789") != std::string::npos)
      return false;
    number = std::stol(digits);
    return true;
  }
  return false;
}
}  // namespace

Status Dataset::openReplica(Dataset& d, const DatasetOptions& options) {
  const fs::path dir(d.dir_);
  const fs::path results = dir / "results";
  std::error_code ec;
  if (!fs::is_directory(results, ec)) return Error{results.string() + ": folder does not exist (Replica layout)"};
  std::map<long, std::string> colors, depths;
  for (const auto& entry : fs::directory_iterator(results, ec)) {
    const std::string f = entry.path().filename().string();
    long number = 0;
    if (numberedName(f, "frame", {".jpg", ".png"}, number)) colors[number] = entry.path().string();
    if (numberedName(f, "depth", {".png"}, number)) depths[number] = entry.path().string();
  }
  if (colors.empty()) return Error{results.string() + ": no frameNNNNNN.jpg images"};
  const int64_t period_ns = 1'000'000'000LL / 30;
  for (const auto& [number, path] : colors) {
    auto it = depths.find(number);
    if (it == depths.end()) {
      const std::string msg = fmt::format("{}: depth image for frame {} is missing", path, number);
      if (!options.skip_bad) return Error{msg};
      d.skipped_.push_back(msg);
      continue;
    }
    d.frames_.push_back({number * period_ns, path, it->second, path, it->second, number * period_ns});
  }
  const fs::path traj_path = dir / "traj.txt";
  if (fs::exists(traj_path)) {
    auto text = readTextFile(traj_path.string());
    if (!text) return Error{text.message()};
    auto traj = parseMatrixTrajectory(*text, traj_path.string(), period_ns, ParseOptions{options.skip_bad});
    if (!traj) return Error{traj.message()};
    d.skipped_.insert(d.skipped_.end(), traj->skipped.begin(), traj->skipped.end());
    const long last_frame = colors.rbegin()->first;
    if (traj->skipped.empty() && static_cast<long>(traj->poses.size()) <= last_frame) {
      return Error{fmt::format("{}: has {} poses but the images go up to frame {}", traj_path.string(),
                               traj->poses.size(), last_frame)};
    }
    d.ground_truth_ = std::move(traj->poses);
  }
  for (const fs::path& p : {dir / "cam_params.json", dir.parent_path() / "cam_params.json"}) {
    if (!fs::exists(p)) continue;
    auto text = readTextFile(p.string());
    if (!text) return text.error();
    auto c = parseReplicaCamParams(*text, p.string());
    if (!c) return c.error();
    d.camera_ = c->camera;
    d.depth_scale_ = c->depth_scale;
    d.camera_source_ = p.string();
    break;
  }
  if (d.camera_source_.empty()) d.depth_scale_ = 6553.5;
  return Status::ok();
}

Status Dataset::finishCamera(const DatasetOptions& options) {
  if (options.camera && (options.force_camera || camera_source_.empty())) {
    camera_ = *options.camera;
    camera_source_ = options.camera_origin;
  }
  if (camera_source_.empty()) {
    return Error{dir_ +
                 ": the dataset carries no intrinsics: add calibration.yaml to the folder (keys fx, fy, cx, cy, "
                 "width, height; optional k1 k2 p1 p2 k3, depth_scale), give camera.fx/fy/cx/cy/width/height in "
                 "a --config file, or name a preset with --camera-preset fr1|fr2|fr3|kinect (a TUM recording's "
                 "folder name normally says which: rgbd_dataset_freiburgN_...)"};
  }
  if (camera_.width <= 0 || camera_.height <= 0 || !(camera_.fx > 0) || !(camera_.fy > 0)) {
    return Error{fmt::format("{}: invalid intrinsics from {}", dir_, camera_source_)};
  }
  if (options.undistort && camera_.hasDistortion()) {
    const cv::Matx33d K(camera_.fx, 0, camera_.cx, 0, camera_.fy, camera_.cy, 0, 0, 1);
    const cv::Mat dist(1, 5, CV_64F, camera_.distortion.data());
    cv::initUndistortRectifyMap(K, dist, cv::Mat(), K, cv::Size(camera_.width, camera_.height), CV_32FC1, undistort_x_,
                                undistort_y_);
    camera_.distortion = {0, 0, 0, 0, 0};
  }
  return Status::ok();
}

Expected<std::vector<RgbdFrame>> Dataset::loadAll() const {
  std::vector<RgbdFrame> frames;
  frames.reserve(size());
  for (size_t i = 0; i < size(); ++i) {
    auto f = load(i);
    if (!f) return Error{f.message()};
    frames.push_back(std::move(*f));
  }
  return frames;
}

Expected<RgbdFrame> Dataset::load(size_t i) const {
  const FrameFiles& f = frames_.at(i);
  auto rgb = readImage(f.rgb_path, f.rgb_ref, false);
  if (!rgb) return Error{rgb.message()};
  auto depth = readImage(f.depth_path, f.depth_ref, true);
  if (!depth) return Error{depth.message()};
  const cv::Size expected(camera_.width, camera_.height);
  if (rgb->size() != expected) {
    return Error{fmt::format("{}: color image {} is {}x{} but the camera is {}x{}", f.rgb_ref, f.rgb_path, rgb->cols,
                             rgb->rows, camera_.width, camera_.height)};
  }
  if (depth->size() != expected) {
    return Error{fmt::format("{}: depth image {} is {}x{} but the camera is {}x{}", f.depth_ref, f.depth_path,
                             depth->cols, depth->rows, camera_.width, camera_.height)};
  }
  RgbdFrame frame;
  frame.stamp_ns = f.stamp_ns;
  frame.depth_stamp_ns = f.depth_stamp_ns;
  frame.seq = i;
  depth->convertTo(frame.depth, CV_32F, 1.0 / depth_scale_);
  frame.rgb = *rgb;
  if (!undistort_x_.empty()) {
    cv::Mat rgb_u, depth_u;
    cv::remap(frame.rgb, rgb_u, undistort_x_, undistort_y_, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::remap(frame.depth, depth_u, undistort_x_, undistort_y_, cv::INTER_NEAREST, cv::BORDER_CONSTANT);
    frame.rgb = rgb_u;
    frame.depth = depth_u;
  }
  return frame;
}

}  // namespace hxmap::drv
