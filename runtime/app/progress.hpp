// A progress line on stderr for long runs: redrawn in place on a terminal,
// one line per 10% otherwise (logs, CI); none under -q (only warnings and
// errors then).
#pragma once

#include <chrono>
#include <cstdio>
#include <string>

#include <spdlog/spdlog.h>
#include <unistd.h>

namespace hxmap::rt {

class Progress {
 public:
  Progress(std::string what, size_t total)
      : what_(std::move(what)),
        total_(total),
        tty_(isatty(STDERR_FILENO) != 0),
        shown_(spdlog::should_log(spdlog::level::info)),
        start_(std::chrono::steady_clock::now()) {}

  void update(size_t done, const std::string& extra = "") {
    if (!shown_) return;
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    const double rate = s > 0 ? static_cast<double>(done) / s : 0.0;
    const int pct = total_ ? static_cast<int>(100 * done / total_) : 100;
    if (tty_) {
      const int bar = pct / 5;
      std::fprintf(stderr, "\r%s [%-20s] %zu/%zu %5.1f/s %s   ", what_.c_str(), std::string(bar, '#').c_str(), done,
                   total_, rate, extra.c_str());
      if (done >= total_) std::fputc('\n', stderr);
    } else if (pct / 10 != last_decile_ || done >= total_) {
      last_decile_ = pct / 10;
      std::fprintf(stderr, "%s %3d%% (%zu/%zu, %.1f/s) %s\n", what_.c_str(), pct, done, total_, rate, extra.c_str());
    }
    std::fflush(stderr);
  }

 private:
  std::string what_;
  size_t total_;
  bool tty_;
  bool shown_;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace hxmap::rt
