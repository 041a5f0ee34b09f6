// Parsers for dataset text files. They take the file's content and a source
// name (used in messages as "name:line"), so they are testable and fuzzable
// without files. A bad line is an error naming file and line, unless
// skip_bad_lines is set: then it is skipped, counted and described in
// `skipped`.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "hxmap/core/expected.hpp"
#include "hxmap/core/frame.hpp"

namespace hxmap::drv {

struct ParseOptions {
  bool skip_bad_lines = false;
};

struct ListEntry {
  int64_t stamp_ns = 0;
  std::string path;  ///< as written in the list, relative to the dataset folder
  int line = 0;      ///< 1-based line in the list file
};

struct ParsedList {
  std::vector<ListEntry> entries;
  std::vector<std::string> skipped;  ///< one message per skipped line
};

struct ParsedTrajectory {
  Trajectory poses;
  std::vector<int> lines;  ///< source line of each pose
  std::vector<std::string> skipped;
};

/// TUM "timestamp filename" lists (rgb.txt, depth.txt). '#' starts a comment.
/// An empty list (no entries) is an error.
Expected<ParsedList> parseTumList(std::string_view content, const std::string& source, const ParseOptions& options = {});

/// TUM trajectories "timestamp tx ty tz qx qy qz qw" (camera-to-world). NaN or
/// infinite values and quaternions whose norm is not 1 (within 1%) are errors.
Expected<ParsedTrajectory> parseTumTrajectory(std::string_view content, const std::string& source,
                                              const ParseOptions& options = {});

/// One row-major 4x4 camera-to-world matrix per line (Replica traj.txt);
/// stamps are line_index * frame_period_ns. Non-rigid matrices are errors.
Expected<ParsedTrajectory> parseMatrixTrajectory(std::string_view content, const std::string& source,
                                                 int64_t frame_period_ns, const ParseOptions& options = {});

/// TUM trajectory text for `trajectory` (stamps with 6 decimals).
std::string formatTumTrajectory(const Trajectory& trajectory);

}  // namespace hxmap::drv
