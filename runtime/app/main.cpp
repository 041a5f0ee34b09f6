// hxmap: real-time dense RGB-D mapping. See README.md for the commands.
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>
#include <cstdlib>

#include "commands.hpp"
#include "hxmap/frontend/frontend.hpp"

int main(int argc, char** argv) {
  // An image whose header claims more than 8192 x 8192 pixels (the largest
  // camera hxmap accepts) is refused by OpenCV's decoders instead of
  // allocating for it (its default allows 2^30 pixels).
  ::setenv("OPENCV_IO_MAX_IMAGE_PIXELS", "67108864", 0);
  hxmap::rt::keepHeapBetweenFrames();
  spdlog::set_default_logger(spdlog::stderr_color_mt("hxmap"));
  spdlog::set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");

  CLI::App app{"hxmap: real-time dense RGB-D mapping"};
  app.set_version_flag("--version", std::string("hxmap " HXMAP_VERSION " (built with: " HXMAP_PARTS ")"));
  app.require_subcommand(1);
  bool quiet = false, verbose = false;
  app.add_flag("-q,--quiet", quiet, "only warnings and errors on stderr");
  app.add_flag("-v,--verbose", verbose, "per-frame details on stderr");

  hxmap::rt::RunOptions run;
  auto* run_cmd = app.add_subcommand(
      "run",
      "map a dataset folder (TUM or Replica layout) offline as fast as possible, or in real time; or a live camera");
  auto* dataset_opt = run_cmd->add_option("--dataset", run.dataset, "dataset folder");
  auto* camera_opt = run_cmd->add_option(
      "--camera", run.camera,
      "live camera, mapped in real time until stopped (Ctrl-C): v4l2:COLOR_DEV+DEPTH_DEV, openni2[:URI|file.oni], "
      "libcamera[:ID]+v4l2:DEPTH_DEV; calibration from the rig: section");
  dataset_opt->excludes(camera_opt);
  run_cmd->add_option("--config", run.config, "YAML configuration (default: built-in defaults)");
  run_cmd->add_option("--out", run.out_dir,
                      "output folder (trajectory.txt, mesh.ply, summary.txt), replaced as a whole when the run ends; "
                      "{time} in it becomes the UTC start time");
  run_cmd->add_flag("--overwrite", run.overwrite, "replace a finished run in --out (kept otherwise: the run refuses)");
  run_cmd->add_option("--max-frames", run.max_frames, "process at most this many frames")
      ->check(CLI::Range(1, 1000000000));
  run_cmd->add_option("--camera-preset", run.camera_preset,
                      "intrinsics by name for a dataset without its own: fr1, fr2, fr3 (TUM freiburg 1/2/3) or kinect "
                      "(525, 319.5, 239.5)")
      ->check(CLI::IsMember({"fr1", "fr2", "fr3", "kinect"}));
  run_cmd->add_flag("--fuse-ground-truth", run.fuse_ground_truth,
                    "fuse every frame at its ground-truth pose instead of tracking (to measure what tracking costs "
                    "the map)");
  run_cmd->add_option("--trace", run.trace, "write per-frame stage timings as a Chrome/Perfetto trace (JSON)");
  run_cmd->add_flag("--realtime", run.realtime,
                    "play the dataset at its recorded rate through the runtime threads (frames load first)");
  run_cmd->add_option("--fps", run.fps, "with --realtime: playback rate instead of the recorded stamps")
      ->check(CLI::Range(0.1, 1000.0));
  run_cmd->add_option("--save-quality", run.save_quality,
                      "folder for quality indicator images per keyframe, ROI boxes (rois.ply) and block scores");
  run_cmd->add_option("--save-map", run.save_map,
                      "save the map and its keyframe database to this file at the end (atomically)");
  run_cmd->add_option("--load-map", run.load_map, "continue a saved map: relocalize in it first, then map into it");
  run_cmd->add_flag("--skip-bad", run.skip_bad,
                    "skip unreadable frames, bad list lines and corrupt map records (counted, logged)");
  run_cmd->add_flag("--no-mesh-eval", run.no_mesh_eval, "do not score the mesh against gt_mesh.ply");
  run_cmd->add_flag("--dds", run.dds, "publish pose, trajectory, map and health over DDS (as dds.enabled)");

  hxmap::rt::SynthOptions synth;
  auto* synth_cmd = app.add_subcommand("synth", "render a synthetic RGB-D sequence with exact ground truth");
  synth_cmd->add_option("--out", synth.out_dir, "output folder (TUM layout)")->required();
  synth_cmd->add_option("--config", synth.config, "YAML configuration (synthetic section)");
  synth_cmd->add_option("--frames", synth.frames, "number of frames");
  synth_cmd->add_option("--seed", synth.seed, "noise seed");
  synth_cmd->add_option("--fps", synth.fps,
                        "frame rate the trajectory is sampled at (default 30; 10: three times the motion per frame)");
  synth_cmd->add_option("--trajectory", synth.trajectory,
                        "orbit, sweep, inspect, fast (hand-held, jerky), loop (10 s laps looking out at the walls) or "
                        "street (end to end of the street scene and back)");
  synth_cmd->add_option("--blackout", synth.blackout,
                        "START_S:DURATION_S: no depth and black color for that long (the camera keeps moving)");
  synth_cmd->add_option("--drop-every", synth.drop_every,
                        "leave every N-th frame out of the lists (2: every other frame dropped)")
      ->check(CLI::Range(0, 1000));
  synth_cmd->add_option(
      "--scene", synth.scene,
      "room (default), quality (known-bad regions for quality validation) or street (160 m, for long flights)");
  synth_cmd->add_option("--scale", synth.scale,
                        "scene and trajectory scaled by this (0.5: the quality room's thin structures as thin against "
                        "1 cm voxels as at full size against 2 cm)");
  synth_cmd->add_flag("--no-noise", synth.no_noise, "exact depth, no sensor model");
  synth_cmd->add_flag("--handheld-camera", synth.handheld_camera,
                      "a consumer color camera: exposed 12 ms after the depth, 30 ms rolling shutter, 20 ms exposure "
                      "(motion blur), auto exposure +-10 % (config keys synthetic.color_delay_s, rolling_shutter_s, "
                      "exposure_s, gain_variation)");

  std::string demo_out = "hxmap_demo", demo_config;
  auto* demo_cmd = app.add_subcommand("demo", "render the built-in synthetic room and map it, with accuracy");
  demo_cmd->add_option("--out", demo_out, "output folder");
  demo_cmd->add_option("--config", demo_config, "YAML configuration");

  hxmap::rt::EvalOptions eval;
  auto* eval_cmd = app.add_subcommand("eval", "trajectory (ATE/RPE) and mesh accuracy against ground truth");
  eval_cmd->add_option("--traj", eval.traj, "estimated trajectory (TUM format)");
  eval_cmd->add_option("--gt-traj", eval.gt_traj, "ground-truth trajectory (TUM format)");
  eval_cmd->add_option("--rpe-delta", eval.rpe_delta_s, "RPE time delta in seconds");
  eval_cmd->add_option("--mesh", eval.mesh, "reconstructed mesh (PLY)");
  eval_cmd->add_option("--gt-mesh", eval.gt_mesh, "ground-truth mesh (PLY)");
  eval_cmd->add_option("--observed-from", eval.observed_from,
                       "dataset folder whose ground-truth poses decide which ground truth was observed");
  eval_cmd->add_option("--samples", eval.samples, "points sampled per mesh");

  std::string config_path;
  auto* config_cmd = app.add_subcommand("config", "validate a configuration and print the effective values");
  config_cmd->add_option("config", config_path, "YAML configuration");

  hxmap::rt::EchoOptions echo;
  auto* echo_cmd = app.add_subcommand("echo", "print what hxmap publishes on a DDS topic, one line per message");
  echo_cmd
      ->add_option("topic", echo.topic, "pose, odom, trajectory, map, map_chunks, map_cloud, health, tf or tf_static")
      ->required();
  echo_cmd->add_option("--config", echo.config, "YAML configuration (dds section: domain, topic prefix)");
  echo_cmd->add_option("--count", echo.count, "stop after this many messages (default: until Ctrl-C)");
  echo_cmd->add_option("--timeout", echo.timeout_s,
                       "fail when --count messages have not come within this many seconds");
  echo_cmd->add_option("--domain", echo.domain_id, "DDS domain id (default: from the configuration)");
  echo_cmd->add_option("--prefix", echo.prefix, "topic prefix (default: from the configuration)");

  hxmap::rt::MapOptions map;
  auto* map_cmd = app.add_subcommand("map", "a saved map file: info, mesh or export");
  map_cmd->add_option("action", map.action, "info (header and statistics), mesh (PLY) or export (OpenVDB)")
      ->required()
      ->check(CLI::IsMember({"info", "mesh", "export"}));
  map_cmd->add_option("file", map.file, "the map file (hxmap run --save-map)")->required();
  map_cmd->add_option("--out", map.out, "mesh, export: the file to write");
  map_cmd->add_option("--format", map.format, "export: vdb (OpenVDB grids sdf, weight, color)");
  map_cmd->add_option("--config", map.config, "mesh: YAML configuration (mesh section)");
  map_cmd->add_flag("--skip-bad", map.skip_bad, "leave corrupt blocks out (counted) instead of failing");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version are 0; every usage error is hxmap's 2, not one
    // of CLI11's own codes.
    return app.exit(e) == 0 ? 0 : 2;
  }
  spdlog::set_level(verbose ? spdlog::level::debug : quiet ? spdlog::level::warn : spdlog::level::info);
  return hxmap::rt::runReportingExceptions([&] {
    if (*run_cmd) return hxmap::rt::runCommand(run);
    if (*synth_cmd) return hxmap::rt::synthCommand(synth);
    if (*demo_cmd) return hxmap::rt::demoCommand(demo_out, demo_config);
    if (*eval_cmd) return hxmap::rt::evalCommand(eval);
    if (*config_cmd) return hxmap::rt::configCommand(config_path);
    if (*echo_cmd) return hxmap::rt::echoCommand(echo);
    if (*map_cmd) return hxmap::rt::mapCommand(map);
    return 2;
  });
}
