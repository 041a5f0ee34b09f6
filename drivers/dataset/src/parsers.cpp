#include "hxmap/dataset/parsers.hpp"

#include <cmath>
#include <cstdlib>

#include <fmt/format.h>

#include "hxmap/core/stamp.hpp"
#include "hxmap/geometry/se3.hpp"

namespace hxmap::drv {

namespace {

std::vector<std::string_view> splitWords(std::string_view line) {
  std::vector<std::string_view> words;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == ',')) ++i;
    const size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t' && line[i] != ',') ++i;
    if (i > start) words.push_back(line.substr(start, i - start));
  }
  return words;
}

// Calls fn(line_number, line) for each non-blank, non-comment line.
template <typename Fn>
void forEachLine(std::string_view content, Fn&& fn) {
  int number = 0;
  size_t pos = 0;
  while (pos <= content.size()) {
    size_t end = content.find('\n', pos);
    if (end == std::string_view::npos) end = content.size();
    std::string_view line = content.substr(pos, end - pos);
    ++number;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    size_t first = line.find_first_not_of(" \t");
    if (first != std::string_view::npos && line[first] != '#') fn(number, line.substr(first));
    if (end == content.size()) break;
    pos = end + 1;
  }
}

bool parseDouble(std::string_view word, double& out) {
  const std::string s(word);
  char* end = nullptr;
  out = std::strtod(s.c_str(), &end);
  return end != s.c_str() && *end == '\0';
}

// Collects line errors: returns the error to fail with, or records a skip.
struct LineErrors {
  const std::string& source;
  const ParseOptions& options;
  std::vector<std::string>& skipped;
  std::string first_error;

  void add(int line, const std::string& what) {
    const std::string msg = fmt::format("{}:{}: {}", source, line, what);
    if (options.skip_bad_lines) {
      skipped.push_back(msg);
    } else if (first_error.empty()) {
      first_error = msg;
    }
  }
};

}  // namespace

Expected<ParsedList> parseTumList(std::string_view content, const std::string& source, const ParseOptions& options) {
  ParsedList out;
  LineErrors errors{source, options, out.skipped, {}};
  forEachLine(content, [&](int number, std::string_view line) {
    const auto words = splitWords(line);
    if (words.size() < 2) {
      errors.add(number, "expected 'timestamp filename', got '" + std::string(line.substr(0, 80)) + "'");
      return;
    }
    const auto stamp = parseStampNs(words[0]);
    if (!stamp) {
      errors.add(number, "bad timestamp '" + std::string(words[0].substr(0, 40)) + "'");
      return;
    }
    out.entries.push_back({*stamp, std::string(words[1]), number});
  });
  if (!errors.first_error.empty()) return Error{errors.first_error};
  if (out.entries.empty()) return Error{source + ": the list has no entries (expected lines 'timestamp filename')"};
  return out;
}

Expected<ParsedTrajectory> parseTumTrajectory(std::string_view content, const std::string& source,
                                              const ParseOptions& options) {
  ParsedTrajectory out;
  LineErrors errors{source, options, out.skipped, {}};
  forEachLine(content, [&](int number, std::string_view line) {
    const auto words = splitWords(line);
    if (words.size() != 8) {
      errors.add(number, fmt::format("expected 8 values 'timestamp tx ty tz qx qy qz qw', got {}", words.size()));
      return;
    }
    const auto stamp = parseStampNs(words[0]);
    double v[7];
    bool ok = stamp.has_value();
    for (int k = 0; k < 7 && ok; ++k) ok = parseDouble(words[k + 1], v[k]) && std::isfinite(v[k]);
    if (!ok) {
      errors.add(number, "a value is not a finite number");
      return;
    }
    Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
    const double norm = q.norm();
    if (std::abs(norm - 1.0) > 0.01) {
      errors.add(number, fmt::format("quaternion norm {:.4f} is not 1: not a rotation", norm));
      return;
    }
    StampedPose p;
    p.stamp_ns = *stamp;
    p.T_world_cam.linear() = q.normalized().toRotationMatrix();
    p.T_world_cam.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
    out.poses.push_back(p);
    out.lines.push_back(number);
  });
  if (!errors.first_error.empty()) return Error{errors.first_error};
  return out;
}

Expected<ParsedTrajectory> parseMatrixTrajectory(std::string_view content, const std::string& source,
                                                 int64_t frame_period_ns, const ParseOptions& options) {
  ParsedTrajectory out;
  LineErrors errors{source, options, out.skipped, {}};
  int64_t index = 0;
  forEachLine(content, [&](int number, std::string_view line) {
    const int64_t this_index = index++;
    const auto words = splitWords(line);
    if (words.size() != 16) {
      errors.add(number, fmt::format("expected 16 values (row-major 4x4 matrix), got {}", words.size()));
      return;
    }
    Eigen::Matrix4d T;
    for (int k = 0; k < 16; ++k) {
      if (!parseDouble(words[k], T(k / 4, k % 4)) || !std::isfinite(T(k / 4, k % 4))) {
        errors.add(number, fmt::format("value {} is not a finite number", k + 1));
        return;
      }
    }
    if (!alg::isRigid(T, 1e-3)) {
      errors.add(number, "the matrix is not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)");
      return;
    }
    StampedPose p;
    p.stamp_ns = this_index * frame_period_ns;
    p.T_world_cam.matrix() = T;
    // Re-orthonormalize the rotation (text has limited precision).
    const Eigen::Quaterniond q(T.topLeftCorner<3, 3>());
    p.T_world_cam.linear() = q.normalized().toRotationMatrix();
    out.poses.push_back(p);
    out.lines.push_back(number);
  });
  if (!errors.first_error.empty()) return Error{errors.first_error};
  return out;
}

std::string formatTumTrajectory(const Trajectory& trajectory) {
  std::string out = "# timestamp tx ty tz qx qy qz qw\n";
  for (const auto& p : trajectory) {
    const Eigen::Quaterniond q(p.T_world_cam.linear());
    const Eigen::Vector3d t = p.T_world_cam.translation();
    out += fmt::format("{} {:.6f} {:.6f} {:.6f} {:.6f} {:.6f} {:.6f} {:.6f}\n", formatStampS(p.stamp_ns), t.x(), t.y(),
                       t.z(), q.x(), q.y(), q.z(), q.w());
  }
  return out;
}

}  // namespace hxmap::drv
