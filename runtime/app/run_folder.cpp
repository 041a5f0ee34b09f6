#include "run_folder.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <set>
#include <utility>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "hxmap/dataset/parsers.hpp"

namespace hxmap::rt {
namespace fs = std::filesystem;

namespace {

constexpr const char* kManifest = ".hxmap-run";
constexpr const char* kLock = ".hxmap-lock";

std::string utcStamp(int64_t unix_s) {
  const std::time_t t = static_cast<std::time_t>(unix_s);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y%m%d-%H%M%S", &tm);
  return buf;
}

std::string errnoText() { return std::strerror(errno); }

/// Flushes a file or folder to disk (best effort for folders: some file
/// systems refuse fsync on them).
bool syncPath(const fs::path& p, bool directory) {
  const int fd = ::open(p.c_str(), (directory ? O_RDONLY | O_DIRECTORY : O_RDONLY) | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0 || directory;
  ::close(fd);
  return ok;
}

/// Outputs of runs from before the manifest: what a run of this program
/// wrote into its folder.
bool isLegacyOutput(const std::string& name) {
  static const std::set<std::string> kNames = {"trajectory.txt", "trajectory_live.txt", "mesh.ply", "summary.txt"};
  return kNames.count(name) > 0 || (name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0);
}

/// Takes the staging folder's lock; -1 when another process holds it.
int lockFolder(const fs::path& dir, std::string& error) {
  const fs::path lock = dir / kLock;
  const int fd = ::open(lock.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    error = fmt::format("{}: cannot create the lock file: {}", lock.string(), errnoText());
    return -1;
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    error = fmt::format("{} is being written by another hxmap run (its lock {} is held)", dir.string(), lock.string());
    ::close(fd);
    return -1;
  }
  const std::string pid = std::to_string(::getpid()) + "\n";
  if (::ftruncate(fd, 0) != 0 || ::write(fd, pid.data(), pid.size()) < 0) {
    // The pid is for people looking at the folder; the lock is what counts.
  }
  return fd;
}

}  // namespace

Expected<LiveTrajectoryFile> LiveTrajectoryFile::open(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "w");
  if (!file) return Error{fmt::format("{}: cannot open for writing: {}", path, errnoText())};
  std::fputs("# timestamp tx ty tz qx qy qz qw\n", file);
  std::fflush(file);
  return LiveTrajectoryFile(path, file);
}

void LiveTrajectoryFile::append(int64_t stamp_ns, const Eigen::Isometry3d& T_world_cam) {
  if (!file_ || failed_) return;
  const std::string text = drv::formatTumTrajectory({{stamp_ns, T_world_cam}});
  const size_t line = text.find('\n') + 1;  // after the header
  if (std::fputs(text.c_str() + line, file_) < 0 || std::fflush(file_) != 0) {
    spdlog::warn("{}: cannot append the pose ({}); the file is written whole at the end", path_, errnoText());
    failed_ = true;
  }
}

void LiveTrajectoryFile::close() {
  if (file_) std::fclose(file_);
  file_ = nullptr;
}

std::string expandOutPath(const std::string& out, int64_t unix_s) {
  std::string s = out;
  for (size_t at; (at = s.find("{time}")) != std::string::npos;) s.replace(at, 6, utcStamp(unix_s));
  return s;
}

std::vector<std::string> runManifest(const std::string& out) {
  std::vector<std::string> names;
  std::ifstream in(fs::path(out) / kManifest);
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line.find('/') == std::string::npos && line != "." && line != "..") names.push_back(line);
  }
  return names;
}

RunFolder::RunFolder(RunFolder&& o) noexcept
    : out_(std::move(o.out_)),
      staging_(std::move(o.staging_)),
      notice_(std::move(o.notice_)),
      lock_fd_(std::exchange(o.lock_fd_, -1)),
      done_(std::exchange(o.done_, true)) {}

RunFolder& RunFolder::operator=(RunFolder&& o) noexcept {
  if (this != &o) {
    if (!done_ && !staging_.empty()) discard();
    if (lock_fd_ >= 0) ::close(lock_fd_);
    out_ = std::move(o.out_);
    staging_ = std::move(o.staging_);
    notice_ = std::move(o.notice_);
    lock_fd_ = std::exchange(o.lock_fd_, -1);
    done_ = std::exchange(o.done_, true);
  }
  return *this;
}

RunFolder::~RunFolder() {
  if (!done_ && !staging_.empty()) discard();
  if (lock_fd_ >= 0) ::close(lock_fd_);
}

Expected<RunFolder> RunFolder::open(const std::string& out_arg, bool overwrite) {
  fs::path out = fs::path(out_arg).lexically_normal();
  if (out.has_filename() == false) out = out.parent_path();  // "o/" -> "o"
  if (out.empty() || out.filename() == "." || out.filename() == ".." || out == out.root_path()) {
    return Error{fmt::format("--out '{}': name a folder of its own (e.g. 'runs/{{time}}')", out_arg)};
  }
  std::error_code ec;
  if (fs::exists(out, ec) && !fs::is_directory(out, ec)) {
    return Error{fmt::format("{}: exists and is not a folder", out.string())};
  }
  const bool finished = fs::exists(out / kManifest, ec) || fs::exists(out / "summary.txt", ec);
  if (finished && !overwrite) {
    return Error{fmt::format(
        "{} holds a finished run (its summary.txt): pass --overwrite to replace it once this run completes, or "
        "choose another --out (e.g. '{}-{{time}}' for one folder per run)",
        out.string(), out.string())};
  }
  // The staging folder is this object's (removed when not committed) only
  // once created below.
  RunFolder f;
  f.out_ = out.string();
  const std::string staging_path = out.string() + ".partial";
  if (!out.parent_path().empty()) {
    fs::create_directories(out.parent_path(), ec);
    if (ec) return Error{fmt::format("{}: cannot create the folder: {}", out.parent_path().string(), ec.message())};
  }
  const fs::path staging(staging_path);
  if (fs::exists(staging, ec)) {
    // Left by a run that was killed (its lock died with it), or being
    // written right now by another run (the lock is held).
    std::string error;
    const int fd = lockFolder(staging, error);
    if (fd < 0) return Error{error};
    ::close(fd);
    const std::string aside = fmt::format("{}.interrupted-{}", f.out_, utcStamp(std::time(nullptr)));
    fs::remove(staging / kLock, ec);
    fs::rename(staging, aside, ec);
    if (ec) return Error{fmt::format("{}: cannot move an interrupted run aside: {}", staging_path, ec.message())};
    f.notice_ = fmt::format("an earlier run into {} was interrupted; what it wrote is kept in {}", f.out_, aside);
  }
  const bool created = fs::create_directory(staging, ec);
  if (ec) return Error{fmt::format("{}: cannot create the run's folder: {}", staging_path, ec.message())};
  if (!created)
    return Error{fmt::format("{} is being written by another hxmap run (it was just created)", staging_path)};
  f.staging_ = staging_path;
  std::string error;
  f.lock_fd_ = lockFolder(staging, error);
  if (f.lock_fd_ < 0) return Error{error};
  return f;
}

std::string RunFolder::path(const std::string& name) const { return (fs::path(staging_) / name).string(); }

bool isUnder(const std::string& path, const std::string& dir) {
  if (path.empty() || dir.empty()) return false;
  const fs::path rel = fs::absolute(fs::path(path))
                           .lexically_normal()
                           .lexically_relative(fs::absolute(fs::path(dir)).lexically_normal());
  return !rel.empty() && *rel.begin() != "..";
}

std::string RunFolder::redirect(const std::string& user_path) const {
  if (!isUnder(user_path, out_)) return user_path;
  const fs::path rel = fs::absolute(fs::path(user_path))
                           .lexically_normal()
                           .lexically_relative(fs::absolute(fs::path(out_)).lexically_normal());
  return rel == "." ? staging_ : (fs::path(staging_) / rel).string();
}

void RunFolder::discard() {
  std::error_code ec;
  fs::remove_all(staging_, ec);
  if (ec) spdlog::warn("{}: cannot remove: {}", staging_, ec.message());
  done_ = true;
}

Status RunFolder::commit() {
  done_ = true;  // from here on, the staging folder is never removed unasked
  const fs::path staging(staging_), out(out_);
  std::error_code ec;
  fs::remove(staging / kLock, ec);  // the lock stays held through the open descriptor
  // The manifest: what this run wrote, so the next run knows what to
  // replace and what to keep.
  std::string manifest;
  for (const auto& e : fs::directory_iterator(staging, ec)) manifest += e.path().filename().string() + "\n";
  {
    std::ofstream m(staging / kManifest, std::ios::trunc);
    m << manifest;
    if (!m) return Error{fmt::format("{}: cannot write the run's manifest", (staging / kManifest).string())};
  }
  for (const auto& e : fs::recursive_directory_iterator(staging, ec)) {
    if (e.is_regular_file(ec) && !syncPath(e.path(), false)) {
      return Error{fmt::format("{}: cannot flush to disk: {}", e.path().string(), errnoText())};
    }
    if (e.is_directory(ec)) syncPath(e.path(), true);
  }
  syncPath(staging, true);

  if (!fs::exists(out, ec)) {
    fs::rename(staging, out, ec);
    if (ec) return Error{fmt::format("{} -> {}: cannot rename: {}", staging_, out_, ec.message())};
  } else {
    std::set<std::string> previous_outputs;
    for (const auto& n : runManifest(out_)) previous_outputs.insert(n);
    const bool legacy = previous_outputs.empty();
    if (::renameat2(AT_FDCWD, staging.c_str(), AT_FDCWD, out.c_str(), RENAME_EXCHANGE) != 0) {
      // A file system without the exchange: two renames, with a moment in
      // which OUT does not exist (never a mix of two runs).
      spdlog::warn("{}: the file system cannot exchange folders atomically ({}); replacing it in two steps", out_,
                   errnoText());
      const fs::path old = out_ + ".previous";
      fs::remove_all(old, ec);
      fs::rename(out, old, ec);
      if (ec) return Error{fmt::format("{}: cannot move the previous run aside: {}", out_, ec.message())};
      fs::rename(staging, out, ec);
      if (ec) return Error{fmt::format("{} -> {}: cannot rename: {}", staging_, out_, ec.message())};
      fs::rename(old, staging, ec);
      if (ec) return Error{fmt::format("{}: cannot move the previous run aside: {}", out_, ec.message())};
    }
    // The previous set is now at the staging path: what no run wrote goes
    // back into OUT; the rest goes.
    for (const auto& e : fs::directory_iterator(staging, ec)) {
      const std::string name = e.path().filename().string();
      const bool output = legacy ? isLegacyOutput(name) : previous_outputs.count(name) > 0 || name == kManifest;
      if (output || name == kLock || fs::exists(out / name)) continue;
      std::error_code move_ec;
      fs::rename(e.path(), out / name, move_ec);
      if (move_ec) spdlog::warn("{}: cannot keep it in {}: {}", e.path().string(), out_, move_ec.message());
    }
    fs::remove_all(staging, ec);
    if (ec) spdlog::warn("{}: cannot remove the previous run: {}", staging_, ec.message());
  }
  syncPath(out.parent_path().empty() ? fs::path(".") : out.parent_path(), true);
  if (lock_fd_ >= 0) {
    ::close(lock_fd_);
    lock_fd_ = -1;
  }
  return Status::ok();
}

}  // namespace hxmap::rt
