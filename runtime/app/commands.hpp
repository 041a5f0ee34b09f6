// The hxmap program's subcommands. Each returns the process exit code:
// 0 success, 1 failure while running, 2 bad usage or configuration.
#pragma once

#include <functional>
#include <string>

#include "hxmap/config/config.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/realtime/realtime.hpp"
#include "hxmap/sync/sync.hpp"

namespace hxmap::rt {

struct RunOptions {
  std::string dataset;
  std::string camera;  ///< live camera spec (runtime/camera); instead of dataset, always real time
  std::string config;  ///< empty = built-in defaults
  /// Where the outputs go, replaced as a whole when the run ends; `{time}`
  /// becomes the UTC start time (one folder per run).
  std::string out_dir = "hxmap_out";
  bool overwrite = false;  ///< replace a finished run in out_dir
  int max_frames = -1;  ///< -1 = from config
  bool skip_bad = false;
  bool no_mesh_eval = false;
  std::string trace;         ///< Chrome trace JSON of per-frame stage timings; empty = none
  bool realtime = false;     ///< play at the recorded rate through the runtime's threads
  double fps = 0;            ///< with realtime: playback rate (0 = recorded stamps)
  std::string save_quality;  ///< folder for indicator images per keyframe, ROI boxes, block scores; empty = none
  /// The map and its keyframe database, saved at the end of the run (a map
  /// file, drivers/mapfile); empty = none.
  std::string save_map;
  /// A saved map to continue: the run relocalizes in it before it fuses
  /// anything (runtime.resume_relocalize_frames, runtime.resume_otherwise).
  std::string load_map;
  bool dds = false;          ///< publish over DDS (also dds.enabled in the configuration)
  /// Intrinsics by name (fr1, fr2, fr3, kinect) for a dataset that carries
  /// none; they win over the dataset's own. Empty: none.
  std::string camera_preset;
  /// Fuse every frame at its ground-truth pose instead of tracking (to
  /// measure what tracking costs the map); needs ground truth.
  bool fuse_ground_truth = false;
};
int runCommand(const RunOptions& options);

struct SynthOptions {
  std::string out_dir;
  std::string config;
  int frames = -1, seed = -1;
  double fps = -1;
  std::string trajectory;
  std::string scene;
  double scale = -1;
  bool no_noise = false;
  std::string blackout;  ///< "START_S:DURATION_S", empty = none
  int drop_every = 0;
  bool handheld_camera = false;  ///< typical color-camera imperfections (see main.cpp)
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

struct MapOptions {
  std::string action;          ///< info, mesh or export
  std::string file;            ///< the map file
  std::string out;             ///< mesh / export: the file to write
  std::string format = "vdb";  ///< export: vdb
  bool skip_bad = false;
  std::string config;  ///< mesh: the mesh section
};
/// Inspects a map file (`hxmap map info|mesh|export`).
int mapCommand(const MapOptions& options);

struct EchoOptions {
  std::string topic;     ///< pose, trajectory, map or health
  std::string config;    ///< for the dds: section; empty = defaults
  int count = 0;         ///< stop after this many messages; 0 = until Ctrl-C
  double timeout_s = 0;  ///< fail when count messages have not come by then; 0 = wait forever
  int domain_id = -1;    ///< -1 = from the configuration
  std::string prefix;    ///< empty = from the configuration
};
/// Prints what hxmap publishes on a topic, one line per message (needs DDS).
int echoCommand(const EchoOptions& options);

/// Runs a command; an exception that reaches here (a bug: every expected
/// failure is reported where it happens) is logged as an error with its
/// message and gives exit code 1 instead of an abort.
int runReportingExceptions(const std::function<int()>& command);

/// The frontend's parameters from a configuration (what `hxmap run` uses).
FrontendParams frontendParams(const HxmapConfig& config);

/// A real-time run's options from a configuration (`hxmap run --realtime`):
/// workers, niceness, the loop closer's pool and the scheduler's margins.
RealtimeOptions realtimeOptions(const HxmapConfig& config, double fps);

/// A live camera pair's calibration from the rig: section.
drv::RigCalibration rigCalibration(const HxmapConfig& config);

}  // namespace hxmap::rt
