// The output folder of one `hxmap run`: a finished run is never lost and a
// reader never sees a mix of two runs.
//
// A run writes into OUT.partial (beside OUT), locked while it runs, with
// its trajectory appended per frame and the mesh checkpointed, so a killed
// run leaves what it had. At the end the whole set replaces OUT in one
// atomic exchange (renameat2 RENAME_EXCHANGE): a reader sees the previous
// set or the new one. Entries of OUT that no run wrote (a `scene/` folder,
// the user's notes) are kept. A folder holding a finished run is replaced
// only with --overwrite; an interrupted run's folder is kept aside as
// OUT.interrupted-<UTC time>.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/core/expected.hpp"

namespace hxmap::rt {

/// `{time}` in an --out path becomes the UTC time (YYYYmmdd-HHMMSS), so a
/// service with fixed arguments writes each run into its own folder.
std::string expandOutPath(const std::string& out, int64_t unix_s);

/// `path` names something inside the folder `dir` (compared as absolute,
/// normalized paths; neither needs to exist).
bool isUnder(const std::string& path, const std::string& dir);

class RunFolder {
 public:
  RunFolder() = default;
  RunFolder(RunFolder&& other) noexcept;
  RunFolder& operator=(RunFolder&& other) noexcept;
  RunFolder(const RunFolder&) = delete;
  RunFolder& operator=(const RunFolder&) = delete;
  /// Releases the lock; an uncommitted staging folder is removed unless
  /// keep() was called (a killed process leaves it for the next run).
  ~RunFolder();

  /// Claims `out` for a run: fails (naming the folder) when OUT holds a
  /// finished run and `overwrite` is false, when another run is writing it,
  /// or when the folder cannot be created. A staging folder left by a
  /// killed run is moved aside first and said so in `notice`.
  static Expected<RunFolder> open(const std::string& out, bool overwrite);

  const std::string& out() const { return out_; }
  const std::string& staging() const { return staging_; }
  /// `name` inside the staging folder.
  std::string path(const std::string& name) const;
  /// A user-given path: under OUT it is redirected into the staging folder
  /// (so it is committed with the set); anywhere else it is left alone.
  std::string redirect(const std::string& user_path) const;
  /// What open() did that the user should hear about (empty: nothing).
  const std::string& notice() const { return notice_; }

  /// Makes the staging folder OUT: everything in it is flushed to disk,
  /// listed in OUT/.hxmap-run, and exchanged with OUT in one step; the
  /// previous set is then removed, keeping what it did not write.
  Status commit();
  /// Leaves OUT as it was; the staging folder is removed.
  void discard();

 private:
  std::string out_, staging_, notice_;
  int lock_fd_ = -1;
  bool done_ = false;
};

/// A trajectory file (TUM format) appended and flushed frame by frame, so a
/// run killed at any moment leaves every pose it had published.
class LiveTrajectoryFile {
 public:
  static Expected<LiveTrajectoryFile> open(const std::string& path);
  LiveTrajectoryFile(LiveTrajectoryFile&& o) noexcept : path_(std::move(o.path_)), file_(o.file_), failed_(o.failed_) {
    o.file_ = nullptr;
  }
  LiveTrajectoryFile(const LiveTrajectoryFile&) = delete;
  LiveTrajectoryFile& operator=(const LiveTrajectoryFile&) = delete;
  LiveTrajectoryFile& operator=(LiveTrajectoryFile&&) = delete;
  ~LiveTrajectoryFile() { close(); }

  /// One pose; a failed write is logged once and the run goes on (the
  /// file is written whole at the end).
  void append(int64_t stamp_ns, const Eigen::Isometry3d& T_world_cam);
  void close();

 private:
  explicit LiveTrajectoryFile(std::string path, std::FILE* file) : path_(std::move(path)), file_(file) {}
  std::string path_;
  std::FILE* file_ = nullptr;
  bool failed_ = false;
};

/// The names a finished run wrote, from OUT/.hxmap-run (empty when OUT is
/// not a run's folder).
std::vector<std::string> runManifest(const std::string& out);

}  // namespace hxmap::rt
