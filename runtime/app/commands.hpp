// The hxmap program's subcommands. Each returns the process exit code:
// 0 success, 1 failure while running, 2 bad usage or configuration.
#pragma once

#include <string>

#include "hxmap/config/config.hpp"
#include "hxmap/frontend/frontend.hpp"

namespace hxmap::rt {

struct RunOptions {
  std::string dataset;
  std::string config;   ///< empty = built-in defaults
  std::string out_dir = "hxmap_out";
  int max_frames = -1;  ///< -1 = from config
  bool skip_bad = false;
  bool no_mesh_eval = false;
  std::string trace;    ///< Chrome trace JSON of per-frame stage timings; empty = none
  bool realtime = false;  ///< play at the recorded rate through the runtime's threads
  double fps = 0;         ///< with realtime: playback rate (0 = recorded stamps)
  double burn_ms = 0;     ///< with realtime: inject CPU-burning refinement slices of this many ms
  std::string save_quality;  ///< folder for indicator images per keyframe, ROI boxes, block scores; empty = none
};
int runCommand(const RunOptions& options);

struct SynthOptions {
  std::string out_dir;
  std::string config;
  int frames = -1, seed = -1;
  std::string trajectory;
  std::string scene;
  bool no_noise = false;
};
int synthCommand(const SynthOptions& options);

/// Generates the default synthetic scene into out_dir/scene and maps it.
int demoCommand(const std::string& out_dir, const std::string& config);

struct EvalOptions {
  std::string traj, gt_traj, mesh, gt_mesh, observed_from;
  double rpe_delta_s = 1.0;
  int samples = 200000;
};
int evalCommand(const EvalOptions& options);

int configCommand(const std::string& config);

/// The frontend's parameters from a configuration (what `hxmap run` uses).
FrontendParams frontendParams(const HxmapConfig& config);

}  // namespace hxmap::rt
