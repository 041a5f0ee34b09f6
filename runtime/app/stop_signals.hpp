// SIGINT/SIGTERM/SIGHUP handling shared by the long-running commands.
#pragma once

#include <atomic>
#include <csignal>

namespace hxmap::rt {

// SIGINT/SIGTERM ask the run to stop: outputs for what was processed are
// still written and the exit code stays 0. SIGHUP (the terminal or the ssh
// session that started the run went away) does the same instead of killing
// the process with nothing written.
inline std::atomic<bool> g_stop{false};
extern "C" inline void onStopSignal(int) { g_stop.store(true); }

class StopSignals {
 public:
  StopSignals() {
    g_stop.store(false);
    struct sigaction sa {};
    sa.sa_handler = onStopSignal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, &old_int_);
    sigaction(SIGTERM, &sa, &old_term_);
    sigaction(SIGHUP, &sa, &old_hup_);
  }
  ~StopSignals() {
    sigaction(SIGINT, &old_int_, nullptr);
    sigaction(SIGTERM, &old_term_, nullptr);
    sigaction(SIGHUP, &old_hup_, nullptr);
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;

 private:
  struct sigaction old_int_ {}, old_term_ {}, old_hup_ {};
};

}  // namespace hxmap::rt
