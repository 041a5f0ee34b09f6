#include "commands.hpp"
#include "quality_output.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <csignal>
#include <ctime>
#include <filesystem>
#include <optional>

#include <unistd.h>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include "checkpoint.hpp"
#include "hxmap/camera/camera_source.hpp"
#include "hxmap/config/config.hpp"
#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/parsers.hpp"
#include "hxmap/dataset/ply.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/mesh_metrics.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/implicit/detail.hpp"
#include "hxmap/mapfile/block_store.hpp"
#include "hxmap/mapfile/map_file.hpp"
#include "hxmap/realtime/realtime.hpp"
#include "hxmap/scheduler/trace.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "parallel.hpp"
#include "progress.hpp"
#include "run_folder.hpp"
#include "sd_notify.hpp"
#include "stop_signals.hpp"
#ifdef HXMAP_HAVE_DDS
#include "dds_glue.hpp"
#endif

namespace fs = std::filesystem;

namespace hxmap::rt {

namespace {

Expected<HxmapConfig> loadAndPrint(const std::string& path) {
  Expected<HxmapConfig> config = path.empty() ? Expected<HxmapConfig>(HxmapConfig{}) : loadConfig(path);
  if (!config) return config;
  // One line at info; the whole effective configuration (a hundred-odd
  // keys) with -v, and always from `hxmap config`.
  spdlog::info("configuration: {} (-v prints every key)", path.empty() ? "built-in defaults" : path);
  spdlog::debug("effective configuration:\n{}", dumpConfig(*config));
  return config;
}

struct Percentiles {
  double median = 0, p90 = 0, max = 0;
};
Percentiles percentiles(std::vector<double> v) {
  Percentiles p;
  if (v.empty()) return p;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  p.median = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
  p.p90 = v[std::min(n - 1, static_cast<size_t>(0.9 * static_cast<double>(n)))];
  p.max = v.back();
  return p;
}

std::string meshScoresText(const alg::MeshScores& s, const alg::MeshMetricsParams& p) {
  return fmt::format(
      "accuracy {:.2f} cm, completion {:.2f} cm, completion ratio@{:.0f}cm {:.1f}%\n"
      "    @{:.0f}cm: precision {:.1f}% recall {:.1f}% F1 {:.1f}%\n"
      "    @{:.0f}cm: precision {:.1f}% recall {:.1f}% F1 {:.1f}%\n",
      s.accuracy_cm, s.completion_cm, p.threshold_coarse_m * 100, 100 * s.completion_ratio_coarse,
      p.threshold_fine_m * 100, 100 * s.precision_fine, 100 * s.recall_fine, 100 * s.f1_fine,
      p.threshold_coarse_m * 100, 100 * s.precision_coarse, 100 * s.recall_coarse, 100 * s.f1_coarse);
}

std::string meshMetricsText(const alg::MeshMetrics& m, const alg::MeshMetricsParams& p,
                            const alg::ObservedBy* observed) {
  if (m.reconstruction_samples == 0 || m.ground_truth_samples == 0) {
    return fmt::format("mesh vs ground truth: n/a ({} is empty)\n",
                       m.reconstruction_samples == 0 ? "the reconstruction" : "the observed ground truth");
  }
  const std::string excluded = observed == nullptr ? ""
                               : observed->min_abs_cos > 0
                                   ? fmt::format(
                                         "; ground truth out of view or seen only at |cos(incidence)| < {:g} "
                                         "(the sensor returns no depth there) excluded",
                                         observed->min_abs_cos)
                                   : "; ground truth out of view excluded";
  std::string out = fmt::format("mesh vs ground truth ({} / {} samples{})\n", m.reconstruction_samples,
                                m.ground_truth_samples, excluded);
  out += "  point-to-surface (nearest triangle):\n    " + meshScoresText(m.point_to_surface, p);
  if (p.point_to_point) {
    out += "  point-to-sampled-point (as many published tables; sampling-limited at fine thresholds):\n    " +
           meshScoresText(m.point_to_point, p);
  }
  return out;
}

/// What the refinement jobs of a run did, for the summary.
struct RefineTally {
  std::vector<double> job_ms, iteration_ms, setup_ms, result_ms;
  size_t jobs = 0, converged = 0, out_of_time = 0, voxels = 0, completed = 0;
  double l1_before = 0, l1_after = 0, memory_mb_max = 0;
  void add(const RefineOutcome& o) {
    const auto& st = o.result.stats;
    ++jobs;
    converged += st.converged;
    out_of_time += o.out_of_time;
    voxels += st.patch_entries;
    completed += st.completed;
    job_ms.push_back(o.setup_ms + o.train_ms + o.result_ms);
    setup_ms.push_back(o.setup_ms);
    result_ms.push_back(o.result_ms);
    if (st.iterations > 0) iteration_ms.push_back(o.train_ms / st.iterations);
    l1_before += st.depth_l1_before_m;
    l1_after += st.depth_l1_after_m;
    memory_mb_max = std::max(memory_mb_max, static_cast<double>(st.memory_bytes) / (1 << 20));
  }
};

alg::MeshMetricsParams meshParams(const EvalConfig& e) {
  alg::MeshMetricsParams p;
  p.samples = e.mesh_samples;
  p.threshold_fine_m = e.threshold_fine_m;
  p.threshold_coarse_m = e.threshold_coarse_m;
  return p;
}

/// `scored` (when given) says whether ATE could be computed: "n/a" and
/// the reason are printed instead of figures that would mean nothing.
std::string trajectoryMetricsText(const Trajectory& est, const Trajectory& gt, double rpe_delta_s,
                                  bool* scored = nullptr) {
  if (scored) *scored = false;
  const alg::AteResult ate = alg::computeAte(est, gt);
  if (ate.pairs == 0) return "ATE: n/a (fewer than 3 poses associate with the ground truth)\n";
  if (!std::isfinite(ate.rmse_m) || !std::isfinite(ate.max_m)) {
    return "ATE: n/a (non-finite poses in the trajectory or the ground truth)\n";
  }
  if (scored) *scored = true;
  std::string out = fmt::format("ATE RMSE {:.2f} cm (mean {:.2f}, median {:.2f}, max {:.2f} cm; {} poses)\n",
                                100 * ate.rmse_m, 100 * ate.mean_m, 100 * ate.median_m, 100 * ate.max_m, ate.pairs);
  const alg::RpeResult rpe = alg::computeRpe(est, gt, static_cast<int64_t>(rpe_delta_s * 1e9));
  if (rpe.pairs == 0 || !std::isfinite(rpe.trans_rmse_m) || !std::isfinite(rpe.rot_rmse_deg)) {
    return out + fmt::format("RPE over {:.2f} s: n/a (no pair of poses {:.2f} s apart)\n", rpe_delta_s, rpe_delta_s);
  }
  return out + fmt::format("RPE over {:.2f} s: translation RMSE {:.2f} cm, rotation RMSE {:.3f} deg ({} pairs)\n",
                           rpe_delta_s, 100 * rpe.trans_rmse_m, rpe.rot_rmse_deg, rpe.pairs);
}

// Tracking's state changes as log lines (not one line per lost frame):
// a warning with the reason when tracking degrades or is lost, an info
// line when it is back, with how long it was away.
class TrackingLog {
 public:
  void add(const FrameResult& r) {
    ++frame_;
    if (r.state == state_) return;
    const double s = static_cast<double>(r.stamp_ns) * 1e-9;
    if (r.state == alg::TrackingState::kTracked) {
      spdlog::info("frame {} ({:.3f}): tracking back ({}) after {} frames {}", frame_ - 1, s,
                   alg::poseSourceName(r.pose_source), frame_ - 1 - since_, alg::trackingStateName(state_));
    } else {
      spdlog::warn("frame {} ({:.3f}): tracking {}: {}", frame_ - 1, s, alg::trackingStateName(r.state), r.failure);
    }
    state_ = r.state;
    since_ = frame_ - 1;
  }

 private:
  alg::TrackingState state_ = alg::TrackingState::kTracked;
  uint64_t frame_ = 0, since_ = 0;
};

std::string trackingSummary(const Frontend& frontend) {
  const alg::TrackingCounts& c = frontend.trackingCounts();
  const TrackingCounters& t = frontend.trackingCounters();
  return fmt::format(
      "tracking: tracked {}, degraded {} ({} followed frame to frame), lost {} ({} times, longest {} frames; {} "
      "given interpolated poses once found again), relocalized {}\n"
      "  relocalization: {} attempts, {:.1f} ms each ({:.1f} ORB, {:.1f} matching and PnP, the rest ICP checks), {} "
      "candidates refused by the ICP check; keyframe database {} "
      "keyframes, {:.1f} MiB, {:.1f} ms per keyframe's features; constant-velocity retries {} ({} better); photometric weight at the end {:.3f} m per unit\n",
      c.tracked, c.degraded, c.odometry_frames, frontend.lostFrames(), c.lost_episodes, c.longest_lost_run,
      t.interpolated_poses, c.relocalized, t.relocalization_attempts,
      t.relocalization_attempts ? t.relocalization_ms / static_cast<double>(t.relocalization_attempts) : 0.0,
      t.relocalization_attempts ? t.relocalization_features_ms / static_cast<double>(t.relocalization_attempts) : 0.0,
      t.relocalization_attempts ? t.relocalization_query_ms / static_cast<double>(t.relocalization_attempts) : 0.0,
      t.relocalization_rejected, t.database_keyframes, static_cast<double>(t.database_bytes) / (1 << 20),
      t.database_keyframes ? t.keyframe_features_ms / static_cast<double>(frontend.keyframes()) : 0.0,
      t.velocity_retries, t.velocity_wins, t.photometric_scale_m);
}

// CLOCK_REALTIME - CLOCK_MONOTONIC now: live cameras stamp frames on the
// monotonic clock, ROS 2 nodes on the real-time one.
[[maybe_unused]] int64_t realtimeMinusMonotonicNs() {
  timespec mono{}, real{};
  clock_gettime(CLOCK_MONOTONIC, &mono);
  clock_gettime(CLOCK_REALTIME, &real);
  return (int64_t{real.tv_sec} - int64_t{mono.tv_sec}) * 1'000'000'000 + (int64_t{real.tv_nsec} - int64_t{mono.tv_nsec});
}

std::string loopClosureSummary(const Frontend& frontend) {
  const LoopClosureCounters l = frontend.loopClosureCounters();
  const LoopCloser* closer = frontend.loopCloser();
  const auto [stored, bytes] = closer ? closer->observations() : std::pair<size_t, size_t>{0, 0};
  return fmt::format(
             "loop closure: {} keyframes ({} made before a correction reached the frontend), {} compared with older "
             "ones "
             "({:.1f} ms each; {} skipped behind newer ones, {} shed), "
             "{} candidates: {} beyond the drift bound, {} refused by the ICP check, {} refused by the pose graph, {} "
             "already "
             "consistent, {} closed and {} applied (largest correction {:.1f} cm, {:.2f} deg); pose graph {} "
             "keyframes, cost "
             "{:.1f} -> {:.1f}, {:.1f} ms solving; tracked motion between keyframes replaced by their alignment {} "
             "times ({} "
             "alignments failed, {} taken unchecked); keyframe map fused in {:.0f} ms, rebuilt {} times from {} "
             "keyframe observations in {:.0f} ms "
             "({} stored, {:.0f} MiB); {} refinement results dropped as stale\n",
             l.keyframes, l.late_keyframes, l.queries, l.queries ? l.detect_ms / static_cast<double>(l.queries) : 0.0,
             l.skipped, l.shed, l.candidates, l.refused_drift, l.refused_icp, l.refused_graph, l.consistent, l.closures,
             l.applied, 100 * l.largest_correction_m, l.largest_correction_deg,
             closer ? closer->graph().nodes().size() : 0, l.cost_before, l.cost_after, l.solve_ms, l.odometry_jumps,
             l.odometry_unverified, l.odometry_unchecked, l.fuse_ms, l.closures, l.keyframes_rebuilt, l.rebuild_ms,
             stored, static_cast<double>(bytes) / (1 << 20), l.stale_refinements) +
         (l.map_bytes_max > 0
              ? fmt::format("  keyframe map under a quarter of the memory budget ({:.0f} MiB): largest {:.1f} MiB "
                            "resident, {} blocks moved out, {} brought back, {} lost\n",
                            static_cast<double>(frontend.loopBudgetBytes()) / (1 << 20),
                            static_cast<double>(l.map_bytes_max) / (1 << 20), l.blocks_moved_out, l.blocks_brought_back,
                            l.blocks_lost)
              : std::string());
}

// ---------------------------------------------------------------- run
//
// runCommand: open the input -> build the pipeline -> run it (real time
// through the runtime's stages, or offline frame by frame) -> write the
// outputs -> summarize. Each step returns what the next one needs.

Error fail(std::string message) { return Error{std::move(message)}; }

// What a run reads: a live camera, or a dataset and the frames of it to map.
struct RunInput {
  std::unique_ptr<CameraSource> camera;   ///< null on a dataset run
  std::unique_ptr<drv::Dataset> dataset;  ///< null on a camera run
  drv::DatasetOptions options;
  std::vector<size_t> frames;  ///< the dataset's frames to map
  int max_frames = 0;          ///< 0: all
  alg::PinholeCamera cam;
  Trajectory no_ground_truth;
  const Trajectory& groundTruth() const { return dataset ? dataset->groundTruth() : no_ground_truth; }
};

// The run's components.
struct RunPipeline {
  ParallelFor parallel;
  FrontendParams params;
  std::unique_ptr<drv::BlockStore> block_store;  ///< tsdf.max_resident_mib; outlives the frontend
  std::unique_ptr<drv::BlockStore> loop_store;   ///< the same, for loop closure's keyframe map
  std::unique_ptr<Frontend> frontend;
#ifdef HXMAP_HAVE_DDS
  std::unique_ptr<dds::Publisher> publisher;
#endif
  bool realtime = false;
  std::string map_text;  ///< what --load-map loaded, for the summary
  RunFolder folder;  ///< where the outputs go (committed to --out at the end)
  std::unique_ptr<LiveTrajectoryFile> live_file;
};

// Under a memory budget: reads a block out of memory from the run's block
// store (a copy, on the caller's thread); null without a budget.
alg::BlockReader blockStoreReader(const RunPipeline& p) {
  drv::BlockStore* store = p.block_store.get();
  if (!store) return {};
  return [store](const alg::BlockKey& k, alg::VoxelBlock& b) { return store->peek(k, b); };
}

// What the run did, for the outputs and the summary.
struct RunRecord {
  explicit RunRecord(const RunOptions& o) : tracing(!o.trace.empty()) {
    trace.nameThread(1, "hx-sensor");  // loading, in an offline run
    trace.nameThread(2, "hx-frontend");
  }
  int64_t sinceStart(std::chrono::steady_clock::time_point t) const {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(t - start).count();
  }
  // A processed frame: logged, its live pose and its stage times kept.
  double add(const FrameResult& r) {
    tracking_log.add(r);
    live.push_back({r.stamp_ns, r.T_world_cam});
    double sum = 0;
    for (int s = 0; s < kStageCount; ++s) {
      // Quality runs on keyframes only: its row is per keyframe.
      if (s != kKeyframe || r.keyframe) stage_ms[s].push_back(r.stage_ms[s]);
      sum += r.stage_ms[s];
    }
    total_ms.push_back(sum);
    return sum;
  }

  const std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  bool tracing;
  TraceRecorder trace;
  TrackingLog tracking_log;
  Trajectory live;  ///< each frame's pose as it was when the frame was processed (published live)
  std::array<std::vector<double>, kStageCount> stage_ms;
  std::vector<double> total_ms;
  std::vector<double> checkpoint_ms;  ///< offline checkpoints of the mesh and trajectory
  size_t bad_frames = 0, frames_without_truth = 0;
  std::string first_error, realtime_report, feedback_text;
  RefineTally refine;
  RunCounters end_counters;  ///< for the last health message
  bool stopped = false;
  double wall_s = 0;
};

// The options that need no input: checked before anything is opened.
Status checkRunOptions(const RunOptions& o) {
  if (!o.camera.empty() && !o.dataset.empty()) return fail("run: give --dataset or --camera, not both");
  if (o.camera.empty() && o.dataset.empty()) return fail("run: give --dataset FOLDER or --camera SPEC");
  if (!o.trace.empty() && !isUnder(o.trace, o.out_dir)) {
    // Checked now, not after the run it would describe.
    const fs::path dir = fs::path(o.trace).parent_path().empty() ? fs::path(".") : fs::path(o.trace).parent_path();
    std::error_code ec;
    if (!fs::is_directory(dir, ec) || ::access(dir.c_str(), W_OK) != 0 || fs::is_directory(o.trace, ec)) {
      return fail(fmt::format("--trace {}: cannot write there (no such folder, not writable, or a folder)", o.trace));
    }
  }
  return {};
}

// Opens the camera (first, so a missing device fails before anything is
// written) or the dataset, and lists the frames to map.
Expected<RunInput> openInput(const RunOptions& o, const HxmapConfig& c) {
  RunInput in;
  if (!o.camera.empty()) {
    auto spec = parseCameraSpec(o.camera);
    if (!spec) return spec.error();
    CameraSourceOptions co;
    co.calibration = rigCalibration(c);
    co.max_sync_gap_s = c.rig.max_sync_gap_s;
    co.fps = c.rig.fps;
    co.reconnect_timeout_s = c.rig.reconnect_timeout_s;
    co.lost_timeout_s = c.rig.lost_timeout_s;
    auto opened = openCameraSource(*spec, co);
    if (!opened) return opened.error();
    in.camera = std::move(*opened);
    const auto& k = in.camera->camera();
    spdlog::info("camera {}: {}x{} at {:.0f} FPS, fx {:.1f} fy {:.1f} cx {:.1f} cy {:.1f}", in.camera->name(), k.width,
                 k.height, in.camera->fps(), k.fx, k.fy, k.cx, k.cy);
  }
  drv::DatasetOptions& dopt = in.options;
  dopt.skip_bad = o.skip_bad || c.dataset.skip_bad_frames;
  dopt.undistort = c.dataset.undistort;
  dopt.max_association_s = c.dataset.max_association_s;
  dopt.depth_scale = c.camera.depth_scale;
  // Intrinsics are never a silent guess: the configuration's stand in for a
  // dataset without its own only when the file gave them; a named preset
  // wins over the dataset's own.
  if (!o.camera_preset.empty()) {
    dopt.camera = drv::cameraPreset(o.camera_preset);
    dopt.camera_origin = "--camera-preset " + o.camera_preset;
    dopt.force_camera = true;
  } else if (c.camera.intrinsics_given) {
    dopt.camera = alg::PinholeCamera{c.camera.fx,
                                     c.camera.fy,
                                     c.camera.cx,
                                     c.camera.cy,
                                     c.camera.width,
                                     c.camera.height,
                                     {c.camera.k1, c.camera.k2, c.camera.p1, c.camera.p2, c.camera.k3}};
    dopt.force_camera = c.camera.override_dataset;
  }
  in.max_frames = o.max_frames >= 0 ? o.max_frames : c.dataset.max_frames;
  if (in.camera) {
    in.cam = in.camera->camera();
    return in;
  }
  auto opened = drv::Dataset::open(o.dataset, dopt);
  if (!opened) return opened.error();
  in.dataset = std::move(*opened);
  const drv::Dataset& ds = *in.dataset;
  in.cam = ds.camera();
  spdlog::info(
      "dataset {}: {} frames, {}x{}, fx {:.1f} fy {:.1f} cx {:.1f} cy {:.1f} (intrinsics from {}), ground "
      "truth: {}",
      ds.dir(), ds.size(), in.cam.width, in.cam.height, in.cam.fx, in.cam.fy, in.cam.cx, in.cam.cy, ds.cameraSource(),
      ds.groundTruth().empty() ? "none" : fmt::format("{} poses", ds.groundTruth().size()));
  for (size_t i = static_cast<size_t>(c.dataset.first_frame); i < ds.size(); i += c.dataset.stride) {
    if (in.max_frames > 0 && in.frames.size() >= static_cast<size_t>(in.max_frames)) break;
    in.frames.push_back(i);
  }
  if (in.frames.empty()) {
    return fail(
        fmt::format("{}: no frames to process (first_frame {} of {})", ds.dir(), c.dataset.first_frame, ds.size()));
  }
  return in;
}

// The frontend at its first pose, the publisher when asked for, the output folder.
// --load-map: the saved map and its keyframes into the frontend, which
// relocalizes in them before it fuses anything.
Status resumeSavedMap(const RunOptions& o, RunPipeline& p) {
  drv::MapLoadOptions lo;
  lo.skip_bad = o.skip_bad;
  lo.tsdf = p.params.tsdf;
  const auto t0 = std::chrono::steady_clock::now();
  auto loaded = drv::loadMap(o.load_map, lo, p.params.relocalization);
  if (!loaded) return Error{"--load-map: " + loaded.message()};
  if (loaded->keyframes.size() == 0) {
    return fail(
        fmt::format("--load-map: {} holds no keyframes to relocalize with (a map saved from frames "
                    "without color?)",
                    o.load_map));
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  p.map_text = fmt::format("map: continued {} ({} blocks, {} keyframes, loaded in {:.2f} s{})", o.load_map,
                           loaded->map.blockCount(), loaded->keyframes.size(), s,
                           loaded->skipped_blocks + loaded->skipped_keyframes > 0
                               ? fmt::format("; {} corrupt blocks and {} keyframes skipped", loaded->skipped_blocks,
                                             loaded->skipped_keyframes)
                               : std::string());
  spdlog::info("{}; relocalizing in it before fusing", p.map_text);
  p.frontend->resumeMap(std::move(loaded->map), std::move(loaded->keyframes));
  return Status::ok();
}

Expected<RunPipeline> buildPipeline(const RunOptions& o, const HxmapConfig& c, const RunInput& in) {
  RunPipeline p;
  p.realtime = o.realtime || in.camera;
  if (o.fuse_ground_truth && (p.realtime || in.groundTruth().empty())) {
    return fail(fmt::format("--fuse-ground-truth: needs an offline run of a dataset with ground truth{}",
                            p.realtime ? " (not --realtime or a camera)" : fmt::format(" ({} has none)", o.dataset)));
  }
  auto folder = RunFolder::open(o.out_dir, o.overwrite);
  if (!folder) return folder.error();
  p.folder = std::move(*folder);
  if (!p.folder.notice().empty()) spdlog::warn("{}", p.folder.notice());
  auto live_file = LiveTrajectoryFile::open(p.folder.path("trajectory_live.txt"));
  if (!live_file) return live_file.error();
  p.live_file = std::make_unique<LiveTrajectoryFile>(std::move(*live_file));
  p.parallel = makeParallelFor(c.runtime.threads);
  p.params = frontendParams(c);
  p.params.wait_for_blocks = !p.realtime;  // a live frame does not wait on the disk
  p.frontend = std::make_unique<Frontend>(in.cam, p.params, p.parallel);
  if (c.tsdf.max_resident_mib > 0) {
    // Scratch space beside the outputs, removed when the run ends.
    auto store = drv::BlockStore::create(p.folder.staging());
    if (!store) return store.error();
    p.block_store = std::move(*store);
    p.frontend->setBlockBacking(p.block_store.get());
    if (c.loop_closure.enabled && c.relocalization.enabled) {
      auto loop_store = drv::BlockStore::create(p.folder.staging());
      if (!loop_store) return loop_store.error();
      p.loop_store = std::move(*loop_store);
      p.frontend->setLoopBlockBacking(p.loop_store.get());
    }
  }
#ifdef HXMAP_HAVE_DDS
  if (o.dds || c.dds.enabled) {
    auto params = publisherParams(c);
    if (!params) return params.error();
    if (in.camera) params->stamp_offset_ns = realtimeMinusMonotonicNs();
    params->read_elsewhere = blockStoreReader(p);
    auto started = dds::Publisher::start(*params);
    if (!started) return started.error();
    p.publisher = std::move(*started);
    spdlog::info("DDS: publishing rt/{}/{{pose,trajectory,map,health}} in domain {}", c.dds.topic_prefix,
                 params->domain_id);
  }
#else
  if (o.dds || c.dds.enabled) {
    return fail(
        "dds: this hxmap was built without Cyclone DDS (apt install cyclonedds-dev cyclonedds-tools, then "
        "configure and build again)");
  }
#endif
  if (!o.load_map.empty()) {
    if (Status s = resumeSavedMap(o, p); !s) return Error{s.message()};
  }
  if (in.camera) {
    // REP 103: the map is z-up. The first camera pose (optical: z forward,
    // x right, y down) is taken as level, looking along the map's x axis.
    p.frontend->setInitialPose(alg::levelOpticalInZUp());
  }
  // A resumed map has its frame already (the run relocalizes in it).
  if (in.dataset && c.dataset.initial_pose == "ground_truth" && !in.groundTruth().empty() && o.load_map.empty()) {
    Eigen::Isometry3d T0;
    if (alg::interpolatePose(in.groundTruth(), in.dataset->stamp(in.frames[0]), 200'000'000, T0)) {
      p.frontend->setInitialPose(T0);
      spdlog::info("first pose taken from the ground truth (the map is in the ground truth's frame)");
    }
  }
  return p;
}

// Under a memory budget a checkpoint's mesh reads the blocks out of memory
// from the block store, on the checkpoint's thread.
CheckpointMesher checkpointMesher(const HxmapConfig& c, const RunPipeline& p) {
  return p.block_store ? CheckpointMesher(c.mesh, blockStoreReader(p)) : CheckpointMesher(c.mesh);
}

// Real time: a dataset's frames are decoded up front (a camera delivers
// decoded frames), then played at their recorded rate through the
// runtime's stages; a camera's frames go through them as they come.
Status runLive(const RunOptions& o, const HxmapConfig& c, RunInput& in, RunPipeline& p, RunRecord& rec) {
  const double mib = static_cast<double>(in.frames.size()) * in.cam.width * in.cam.height * 7 / (1 << 20);
  if (mib > 8192) {
    return fail(fmt::format("--realtime loads every frame first: {} frames need about {:.0f} MiB; use --max-frames",
                            in.frames.size(), mib));
  }
  std::vector<RgbdFrame> loaded;
  Progress loading("loading", in.frames.size());
  for (size_t k = 0; k < in.frames.size() && !g_stop.load(); ++k) {
    auto frame = in.dataset->load(in.frames[k]);
    if (!frame) {
      if (!in.options.skip_bad) {
        // As offline: what comes before the bad frame is still mapped
        // and written, and the run ends with 1.
        rec.first_error = frame.message() + " (use --skip-bad to skip unreadable frames)";
        spdlog::error("{}; playing the {} frames before it", rec.first_error, loaded.size());
        break;
      }
      ++rec.bad_frames;
      spdlog::warn("skipped frame {}: {}", in.frames[k], frame.message());
    } else {
      loaded.push_back(std::move(*frame));
    }
    loading.update(k + 1);
  }
  RealtimeOptions ro = realtimeOptions(c, o.fps);
  // Each pose to disk as it is published (a killed run keeps them all).
  ro.on_frame = [&p](const FrameResult& r, const Frontend& f, [[maybe_unused]] const RunCounters& counters) {
    p.live_file->append(r.stamp_ns, r.T_world_cam);
    if (f.resumeFailed()) g_stop.store(true);  // runtime.resume_otherwise: fail
#ifdef HXMAP_HAVE_DDS
    if (p.publisher) p.publisher->onFrame(r, f.map(), f.trajectory(), counters);
#endif
  };
  // Under systemd (Type=notify): ready once the frames are loaded (the
  // camera streams), then a watchdog heartbeat from the status loop while
  // the run is healthy.
  sdNotify(in.camera ? fmt::format("READY=1\nSTATUS=mapping from {}", in.camera->name())
                     : fmt::format("READY=1\nSTATUS=playing {} frames", loaded.size()));
  const bool watchdog = sdWatchdogUsec() > 0;
  // The map and trajectory into the run's folder every checkpoint_s (the
  // poses go to trajectory_live.txt frame by frame).
  CheckpointMesher mesher = checkpointMesher(c, p);
  CheckpointWriter checkpoints(
      [&](const MapCheckpoint& cp) {
        Status s = drv::writeTextFile(p.folder.path("trajectory.txt"), drv::formatTumTrajectory(cp.trajectory));
        if (s) s = drv::writePly(p.folder.path("mesh.ply"), mesher.mesh(cp));
        if (!s) spdlog::warn("checkpoint: {}", s.message());
      },
      c.runtime.background_nice);
  ro.checkpoint_s = c.runtime.checkpoint_s;
  ro.on_checkpoint = [&checkpoints](MapCheckpoint&& cp) { checkpoints.offer(std::move(cp)); };
  PlaybackSource playback(loaded, o.fps);
  // A dataset's frames are already limited above; a camera's here.
  FrameLimit limited_camera(in.camera ? static_cast<FrameSource&>(*in.camera) : playback,
                            in.camera ? static_cast<size_t>(std::max(0, in.max_frames)) : 0);
  FrameSource& source = in.camera ? static_cast<FrameSource&>(limited_camera) : playback;
  const RealtimeStats rs = runRealtime(source, *p.frontend, ro, g_stop, rec.tracing ? &rec.trace : nullptr, [&] {
    if (watchdog) sdNotify("WATCHDOG=1");
  });
  if (!rs.source_error.empty()) rec.first_error = rs.source_error;
  sdNotify("STOPPING=1\nSTATUS=writing outputs");
  for (const auto& r : rs.results) rec.add(r);
  rec.realtime_report = rs.report;
  rec.stopped = rs.stopped_early;
  rec.end_counters = {rs.counters.frames_dropped, rs.counters.deadline_misses, rs.refine_jobs_completed,
                      rs.refine_jobs_shed, 0};
  return {};
}

// A dataset's frames read one at a time, when the serial run asks for the
// next; with --skip-bad an unreadable frame is skipped and counted, without
// it the run ends there (what came before is mapped and written).
class DatasetFrames : public FrameSource {
 public:
  DatasetFrames(const RunInput& in, RunRecord& rec) : in_(in), rec_(rec) {}
  Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) override {
    while (next_ < in_.frames.size() && !stop.load()) {
      const size_t index = in_.frames[next_++];
      auto frame = in_.dataset->load(index);
      if (frame) return std::optional<RgbdFrame>{std::move(*frame)};
      if (!in_.options.skip_bad) return fail(frame.message() + " (use --skip-bad to skip unreadable frames)");
      ++rec_.bad_frames;
      spdlog::warn("skipped frame {}: {}", index, frame.message());
    }
    return std::optional<RgbdFrame>{};
  }
  double fps() const override { return 30; }  // unused: a serial run has no deadline
  size_t size() const override { return in_.frames.size(); }
  size_t read() const { return next_; }

 private:
  const RunInput& in_;
  RunRecord& rec_;
  size_t next_ = 0;
};

// Offline: the real-time run's stages, one after another on this thread
// (runSerial). ROI jobs run to their iteration cap after the keyframe that
// made them, the pose-feedback window is solved on each new keyframe, loop
// closure takes every step: no wall-clock budget, so the outputs do not
// depend on the machine or its load.
void runOffline(const RunOptions& o, const HxmapConfig& c, RunInput& in, RunPipeline& p, RunRecord& rec) {
  DatasetFrames source(in, rec);
  Progress progress("mapping", in.frames.size());
  bool halt = false;  // an output failed: the run ends after this frame
  RealtimeOptions so;
  so.refine_workers = c.runtime.refine_workers;
  so.loop_parallel = p.parallel;
  so.should_stop = [&halt, &p] { return halt || p.frontend->resumeFailed(); };
  so.on_frame = [&](const FrameResult& r, const Frontend& frontend, const RunCounters& counters) {
    spdlog::debug("frame {}: {} ({}) inliers {} within noise {:.0f} % rms {:.2f} mm, t = [{:.3f} {:.3f} {:.3f}]{}{}",
                  source.read() - 1, alg::trackingStateName(r.state), alg::poseSourceName(r.pose_source), r.inliers,
                  100 * r.consistent_ratio, r.rms_residual_m * 1000, r.T_world_cam.translation().x(),
                  r.T_world_cam.translation().y(), r.T_world_cam.translation().z(), r.failure.empty() ? "" : ": ",
                  r.failure);
    if (r.keyframe && !o.save_quality.empty()) {
      if (auto s = writeKeyframeQuality(o.save_quality, frontend, r.keyframe_id); !s) {
        spdlog::error("{}", s.message());
        rec.first_error = s.message();
        halt = true;
      }
    }
    p.live_file->append(r.stamp_ns, r.T_world_cam);
#ifdef HXMAP_HAVE_DDS
    if (p.publisher) {
      RunCounters with_skipped = counters;
      with_skipped.frames_dropped = rec.bad_frames;
      p.publisher->onFrame(r, frontend.map(), frontend.trajectory(), with_skipped);
    }
#else
    (void)counters;
#endif
    double sum = 0;
    for (double ms : r.stage_ms) sum += ms;
    progress.update(source.read(), fmt::format("{:.1f} ms/frame", sum));
  };
  so.on_refined = [&rec](const RefineOutcome& outcome) { rec.refine.add(outcome); };
  if (o.fuse_ground_truth) {
    so.given_pose = [&](const RgbdFrame& frame, Eigen::Isometry3d& T_world_cam) {
      const int64_t stamp = frame.depth_stamp_ns > 0 ? frame.depth_stamp_ns : frame.stamp_ns;
      const bool found = alg::interpolatePose(in.groundTruth(), stamp, 200'000'000, T_world_cam);
      rec.frames_without_truth += !found;
      return found;
    };
  }
  // The mesh and trajectory so far into the run's folder (replaced at the end).
  so.checkpoint_s = c.runtime.checkpoint_s;
  CheckpointMesher mesher = checkpointMesher(c, p);
  so.on_checkpoint = [&](MapCheckpoint&& cp) {
    const auto t0 = std::chrono::steady_clock::now();
    Status s = drv::writeTextFile(p.folder.path("trajectory.txt"), drv::formatTumTrajectory(cp.trajectory));
    if (s) s = drv::writePly(p.folder.path("mesh.ply"), mesher.mesh(cp));
    if (!s) spdlog::warn("checkpoint: {}", s.message());
    rec.checkpoint_ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  };
  const RealtimeStats rs = runSerial(source, *p.frontend, so, g_stop, rec.tracing ? &rec.trace : nullptr);
  for (const FrameResult& r : rs.results) rec.add(r);
  if (rec.first_error.empty()) rec.first_error = rs.source_error;
  rec.stopped = g_stop.load();
  rec.end_counters = {rec.bad_frames, 0, rec.refine.jobs, 0, 0};
  if (p.params.feedback.enabled) rec.feedback_text = rs.feedback.text(p.frontend->feedbackCounters(), p.params.feedback);
}

// What went to disk; outputs are written even after an error, so nothing
// mapped so far is lost.
struct RunOutputs {
  alg::TriangleMesh mesh;
  std::vector<std::string> written, not_written;
  bool ok() const { return not_written.empty(); }
};

RunOutputs writeOutputs(const HxmapConfig& c, const RunPipeline& p, const RunRecord& rec) {
  RunOutputs out;
  auto write = [&](const std::string& name, const std::function<Status(const std::string&)>& writer) {
    const std::string shown = (fs::path(p.folder.out()) / name).string();
    if (auto s = writer(p.folder.path(name)); !s) {
      spdlog::error("{}", s.message());
      out.not_written.push_back(shown);
    } else {
      out.written.push_back(shown);
    }
  };
  const Frontend& frontend = *p.frontend;
  write("trajectory.txt", [&](const std::string& path) {
    return drv::writeTextFile(path, drv::formatTumTrajectory(frontend.trajectory()));
  });
  p.live_file->close();
  write("trajectory_live.txt",
        [&](const std::string& path) { return drv::writeTextFile(path, drv::formatTumTrajectory(rec.live)); });
  out.mesh = frontend.mesh(c.mesh);
  write("mesh.ply", [&](const std::string& path) { return drv::writePly(path, out.mesh); });
  return out;
}

// The mesh against the dataset's ground-truth mesh, when it has one.
std::string meshScoreText(const RunOptions& o, const HxmapConfig& c, const RunInput& in, const RunPipeline& p,
                          const alg::TriangleMesh& mesh) {
  const fs::path gt_mesh_path = in.dataset ? fs::path(in.dataset->dir()) / "gt_mesh.ply" : fs::path();
  if (!in.dataset || o.no_mesh_eval || !fs::exists(gt_mesh_path)) return {};
  auto gt_mesh = drv::readPly(gt_mesh_path.string());
  if (!gt_mesh) {
    spdlog::error("{}", gt_mesh.message());
    return {};
  }
  spdlog::info("scoring the mesh against {} ...", gt_mesh_path.string());
  // Ground truth counts as observed only from the poses of the frames
  // this run processed (a --max-frames run sees less of the scene).
  alg::ObservedBy observed{in.cam, {}, c.preprocess.max_depth_m, in.dataset->sensorGrazingCos()};
  const int64_t first_ns = in.dataset->stamp(in.frames.front()) - 50'000'000;
  const int64_t last_ns = in.dataset->stamp(in.frames.back()) + 50'000'000;
  for (const auto& pose : in.groundTruth()) {
    if (pose.stamp_ns >= first_ns && pose.stamp_ns <= last_ns) observed.poses.push_back(pose);
  }
  const auto mp = meshParams(c.eval);
  return meshMetricsText(alg::computeMeshMetrics(mesh, *gt_mesh, mp, &observed, p.parallel), mp, &observed);
}

std::string refineText(const Frontend& frontend, const RefineTally& refine) {
  if (refine.jobs == 0) {
    return frontend.refineJobsMade() > 0 ? fmt::format("refinement: {} ROI jobs made\n", frontend.refineJobsMade())
                                         : std::string();
  }
  const auto pj = percentiles(refine.job_ms), pi = percentiles(refine.iteration_ms), ps = percentiles(refine.setup_ms);
  const auto pr = percentiles(refine.result_ms);
  const double n = static_cast<double>(refine.jobs);
  std::string text = fmt::format(
      "refinement: {} ROI jobs ({} converged early, {} stopped by the time budget), {} voxels written back ({} "
      "completed where fusion had none)\n"
      "  per job median {:.0f} ms (setup {:.1f} ms, write-back{} {:.1f} ms), per iteration median "
      "{:.2f} ms, memory per ROI up to {:.1f} MiB\n"
      "  field depth L1 on the ROIs' rays: {:.2f} mm as fused -> {:.2f} mm refined (mean over jobs)\n",
      refine.jobs, refine.converged, refine.out_of_time, refine.voxels, refine.completed, pj.median, ps.median,
      frontend.params().feedback.enabled ? " and field sampling for feedback" : "", pr.median, pi.median,
      refine.memory_mb_max, 1000 * refine.l1_before / n, 1000 * refine.l1_after / n);
  size_t detail_bytes = 0;
  const auto details = frontend.details();
  for (const auto& d : details) detail_bytes += d->memoryBytes();
  if (!details.empty()) {
    text += fmt::format("  detail layer in the mesh: {} regions, {:.1f} MiB\n", details.size(),
                        static_cast<double>(detail_bytes) / (1 << 20));
  }
  return text;
}

// The summary's figures: frames, tracking, map, timing, background work,
// accuracy against the ground truth.
std::string summarize(const RunOptions& o, const HxmapConfig& c, const RunInput& in, const RunPipeline& p,
                      const RunRecord& rec, const RunOutputs& out) {
  const Frontend& frontend = *p.frontend;
  std::string summary = "hxmap run summary\n=================\n";
  summary += in.dataset ? fmt::format("dataset: {} ({} frames)\n", in.dataset->dir(), in.dataset->size())
                        : fmt::format("camera: {}\n", in.camera->name());
  summary += fmt::format(
      "frames: processed {}, unreadable skipped {}, bad list or ground-truth lines skipped {}, "
      "keyframes {}\n",
      rec.total_ms.size(), rec.bad_frames, in.dataset ? in.dataset->skippedAtOpen().size() : 0, frontend.keyframes());
  summary += trackingSummary(frontend);
  if (o.fuse_ground_truth) {
    summary +=
        fmt::format("fused at the ground-truth poses (--fuse-ground-truth); {} frames without one were tracked\n",
                    rec.frames_without_truth);
  }
  const auto mem = frontend.map().memory();
  summary +=
      fmt::format("map: voxel {:.1f} cm, truncation {:.1f} cm, {} blocks, {:.1f} MiB; mesh {} vertices, {} triangles\n",
                  c.tsdf.voxel_size_m * 100, c.tsdf.truncation_m * 100, mem.blocks,
                  static_cast<double>(mem.bytes) / (1 << 20), out.mesh.vertices.size(), out.mesh.triangles.size());
  summary += "timing, ms per frame    median      p90      max\n";
  for (int s = 0; s < kStageCount; ++s) {
    const auto ps = percentiles(rec.stage_ms[s]);
    summary += fmt::format("  {:<18} {:>8.2f} {:>8.2f} {:>8.2f}\n",
                           s == kKeyframe ? "keyframe (quality, ORB)" : stageName(s), ps.median, ps.p90, ps.max);
  }
  const auto pt = percentiles(rec.total_ms);
  summary += fmt::format("  {:<18} {:>8.2f} {:>8.2f} {:>8.2f}\n", "frontend total", pt.median, pt.p90, pt.max);
  if (p.realtime) {
    summary += rec.realtime_report;
  } else {
    summary += fmt::format("throughput: {:.1f} frames/s over {:.1f} s wall (image loading included, {} threads)\n",
                           static_cast<double>(rec.total_ms.size()) / rec.wall_s, rec.wall_s,
                           c.runtime.threads > 0 ? std::to_string(c.runtime.threads) : "all");
  }
  if (!rec.checkpoint_ms.empty()) {
    summary += fmt::format("checkpoints: {} (mesh and trajectory every {:g} s), median {:.0f} ms each\n",
                           rec.checkpoint_ms.size(), c.runtime.checkpoint_s, percentiles(rec.checkpoint_ms).median);
  }
  summary += rec.feedback_text;
  if (p.params.loop_closure.enabled) summary += loopClosureSummary(frontend);
  if (!in.groundTruth().empty()) {
    summary += trajectoryMetricsText(frontend.trajectory(), in.groundTruth(), c.eval.rpe_delta_s);
    if (frontend.loopClosureCounters().applied > 0) {
      summary += "as published live (trajectory_live.txt):\n" +
                 trajectoryMetricsText(rec.live, in.groundTruth(), c.eval.rpe_delta_s);
    }
  }
  summary += meshScoreText(o, c, in, p, out.mesh);
  summary += qualityText(frontend);
  return summary;
}

// Honest exit codes: a run that mapped nothing (or lost more than the
// configured share) did not succeed, whatever it wrote. Empty: it did.
std::string runFailure(const HxmapConfig& c, const Frontend& frontend) {
  const size_t processed = frontend.trajectory().size(), lost = frontend.lostFrames();
  if (frontend.resumeFailed()) {
    return fmt::format(
        "not relocalized in the saved map within {} frames (runtime.resume_relocalize_frames; "
        "runtime.resume_otherwise: new_map starts a new map instead)",
        c.runtime.resume_relocalize_frames);
  }
  if (processed > 0 && frontend.trackingCounts().tracked == 0) {
    return fmt::format("nothing was mapped: none of the {} frames was tracked well enough to fuse", processed);
  }
  if (processed > 0 && static_cast<double>(lost) > c.runtime.max_lost_share * static_cast<double>(processed)) {
    return fmt::format("{} of {} frames lost, more than runtime.max_lost_share ({:g})", lost, processed,
                       c.runtime.max_lost_share);
  }
  return {};
}

// tsdf.max_resident_mib: how the budget held and what it cost.
std::string memoryText(const HxmapConfig& c, const MemoryCounters& m, const drv::BlockStoreStats& s,
                       size_t frame_count) {
  const double frames = std::max<double>(1.0, static_cast<double>(frame_count));
  return fmt::format(
             "memory: budget {:g} MiB, voxels resident at most {:.1f} MiB ({} frames over the budget); {} blocks moved "
             "out, {} brought back ({} ahead "
             "of the camera, {} in view left for later frames, {} of them not read yet), {} lost; store {:.1f} MiB on "
             "disk, {:.1f} MiB written; "
             "moving out {:.2f} ms per frame (max {:.1f}), bringing back {:.2f} ms (max {:.1f})\n",
             c.tsdf.max_resident_mib, static_cast<double>(m.resident_bytes_max) / (1 << 20), m.frames_over_budget,
             m.evicted, m.taken_back, m.prefetched, m.prefetch_capped + m.prefetch_not_ready, m.prefetch_not_ready,
             m.lost, static_cast<double>(s.file_bytes) / (1 << 20), static_cast<double>(s.bytes_written) / (1 << 20),
             m.evict_ms_total / frames, m.evict_ms_max, m.prefetch_ms_total / frames, m.prefetch_ms_max) +
         (s.write_failures > 0
              ? fmt::format("memory: the disk refused {} blocks (kept in memory instead)\n", s.write_failures)
              : std::string());
}

std::string resumeText(const RunPipeline& p) {
  const Frontend& f = *p.frontend;
  std::string text = p.map_text;
  if (f.resumedAtFrame() >= 0) {
    text += fmt::format("; relocalized in it at frame {}", f.resumedAtFrame());
  } else if (f.resumeAbandoned()) {
    text += "; not relocalized in it: set aside, a new map was started (runtime.resume_otherwise: new_map)";
  } else {
    text += "; not relocalized in it";
  }
  return text + "\n";
}

// --save-map: the map and its keyframe database, atomically.
std::string saveMapText(const RunOptions& o, const Frontend& frontend) {
  if (frontend.trackingCounts().tracked == 0 && !frontend.resuming()) {
    spdlog::warn("--save-map: this run mapped nothing; {} not written", o.save_map);
    return fmt::format("map: not saved to {} (nothing was mapped)\n", o.save_map);
  }
  const auto t0 = std::chrono::steady_clock::now();
  const auto saved = drv::saveMap(o.save_map, frontend.map(), &frontend.keyframeDatabase());
  if (!saved) {
    spdlog::error("--save-map: {}", saved.message());
    return fmt::format("map: not saved to {} (see the error)\n", o.save_map);
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return fmt::format("map: saved {} ({} blocks, {} keyframes, {:.1f} MiB in {:.2f} s)\n", o.save_map, saved->blocks,
                     saved->keyframes, static_cast<double>(saved->bytes) / (1 << 20), s);
}

}  // namespace

int runCommand(const RunOptions& options) {
  RunOptions o = options;
  o.out_dir = expandOutPath(options.out_dir, static_cast<int64_t>(std::time(nullptr)));
  auto config = loadAndPrint(o.config);
  if (!config) {
    spdlog::error("{}", config.message());
    return 2;
  }
  const HxmapConfig& c = *config;
  if (Status s = checkRunOptions(o); !s) {
    spdlog::error("{}", s.message());
    return 2;
  }
  Expected<RunInput> input = openInput(o, c);
  if (!input) {
    spdlog::error("{}", input.message());
    return 2;
  }
  Expected<RunPipeline> pipeline = buildPipeline(o, c, *input);
  if (!pipeline) {
    spdlog::error("{}", pipeline.message());
    return 2;
  }
  RunInput& in = *input;
  RunPipeline& p = *pipeline;
  const Frontend& frontend = *p.frontend;
  // Quality images and the trace asked for inside --out go with the set.
  o.save_quality = p.folder.redirect(o.save_quality);
  o.trace = p.folder.redirect(o.trace);

  StopSignals signals;
  RunRecord rec(o);
  if (p.realtime) {
    if (Status s = runLive(o, c, in, p, rec); !s) {
      spdlog::error("{}", s.message());
      return 2;
    }
  } else {
    runOffline(o, c, in, p, rec);
  }
  rec.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - rec.start).count();
  // The outputs cover the whole map: blocks out of memory come back.
  const MemoryCounters memory_in_run = p.frontend->memoryCounters();
  p.frontend->restoreEvicted();
  std::string memory_text;
  if (p.block_store) {
    memory_text = memoryText(c, memory_in_run, p.block_store->stats(), p.frontend->trajectory().size());
    p.frontend->setBlockBacking(nullptr);
    p.block_store.reset();  // its scratch file goes before the folder is committed
  }
  if (p.loop_store) {
    p.frontend->setLoopBlockBacking(nullptr);  // the keyframe map's blocks out are not an output
    p.loop_store.reset();
  }
#ifdef HXMAP_HAVE_DDS
  std::string dds_text;
  if (p.publisher) {
    // Everything mapped goes out before the program ends (transient-local
    // readers that join while it is still up get the whole map).
    p.publisher->flush(frontend.map(), frontend.trajectory(), rec.end_counters);
    dds_text = publisherStatsText(p.publisher->stats(), rec.wall_s);
  }
#endif

  const RunOutputs out = writeOutputs(c, p, rec);
  int exit_code = rec.first_error.empty() && out.ok() ? 0 : 1;
  std::string summary = summarize(o, c, in, p, rec, out);
  if (!p.map_text.empty()) summary += resumeText(p);
  summary += memory_text;
  if (!o.save_map.empty()) {
    const std::string text = saveMapText(o, frontend);
    summary += text;
    if (text.find("not saved") != std::string::npos) exit_code = 1;
  }
#ifdef HXMAP_HAVE_DDS
  summary += dds_text;
#endif
  summary += refineText(frontend, rec.refine);
  if (!o.save_quality.empty()) {
    if (auto s = writeQualityMaps(o.save_quality, frontend); !s) {
      spdlog::error("{}", s.message());
      exit_code = 1;
    } else {
      summary +=
          fmt::format("quality: indicator images per keyframe, rois.ply and blocks.csv in {}\n", options.save_quality);
    }
  }
  summary += fmt::format("outputs: {}\n",
                         out.written.empty() ? std::string("none") : fmt::format("{}", fmt::join(out.written, ", ")));
  if (!out.not_written.empty()) {
    summary += fmt::format("not written (see the errors): {}\n", fmt::join(out.not_written, ", "));
  }
  if (!rec.first_error.empty()) summary += "stopped early: " + rec.first_error + "\n";
  if (rec.stopped) summary += "stopped early by a signal: outputs cover the frames processed until then\n";
  if (const std::string failure = runFailure(c, frontend); !failure.empty()) {
    summary += "result: failed, " + failure + "\n";
    spdlog::error("{}", failure);
    exit_code = 1;
  }
  if (rec.tracing) {
    if (auto s = rec.trace.write(o.trace); !s) {
      spdlog::error("{}", s.message());
      exit_code = 1;
    } else {
      summary += fmt::format("trace: {} ({} events; open in ui.perfetto.dev)\n", options.trace, rec.trace.size());
    }
  }
  // A run that mapped nothing leaves --out as it was (a finished run in it
  // is not replaced by an empty one); any other run replaces it as a whole.
  if (frontend.trackingCounts().tracked == 0) {
    summary += fmt::format("{} left as it was: this run mapped nothing\n", p.folder.out());
    p.folder.discard();
  } else {
    if (auto s = drv::writeTextFile(p.folder.path("summary.txt"), summary); !s) {
      spdlog::error("{}", s.message());
      exit_code = 1;
    }
    if (auto s = p.folder.commit(); !s) {
      spdlog::error("{} (this run's outputs are in {})", s.message(), p.folder.staging());
      exit_code = 1;
    }
  }
  std::fputs(summary.c_str(), stdout);
  return exit_code;
}

int synthCommand(const SynthOptions& o) {
  auto config = loadAndPrint(o.config);
  if (!config) {
    spdlog::error("{}", config.message());
    return 2;
  }
  const SyntheticConfig& sc = config->synthetic;
  drv::SyntheticParams p;
  // The configuration's camera, when it gives one, renders the frames (a
  // pinhole: the renderer has no lens distortion to apply).
  if (const CameraConfig& cc = config->camera; cc.intrinsics_given) {
    if (cc.k1 != 0 || cc.k2 != 0 || cc.p1 != 0 || cc.p2 != 0 || cc.k3 != 0) {
      spdlog::error("camera: synthetic frames are rendered without lens distortion; set k1, k2, p1, p2, k3 to 0");
      return 2;
    }
    p.camera = alg::PinholeCamera{cc.fx, cc.fy, cc.cx, cc.cy, cc.width, cc.height, {0, 0, 0, 0, 0}};
  }
  p.frames = o.frames > 0 ? o.frames : sc.frames;
  p.seed = static_cast<uint64_t>(o.seed >= 0 ? o.seed : sc.seed);
  p.fps = o.fps > 0 ? o.fps : sc.fps;
  if (!(p.fps >= 1 && p.fps <= 1000)) {
    spdlog::error("--fps: {} is not within [1, 1000]", p.fps);
    return 2;
  }
  p.trajectory = o.trajectory.empty() ? sc.trajectory : o.trajectory;
  if (p.trajectory != "orbit" && p.trajectory != "sweep" && p.trajectory != "inspect" && p.trajectory != "fast" &&
      p.trajectory != "loop" && p.trajectory != "street") {
    spdlog::error("--trajectory: '{}' is not one of: orbit, sweep, inspect, fast, loop, street", p.trajectory);
    return 2;
  }
  if (!o.blackout.empty()) {
    const size_t colon = o.blackout.find(':');
    char* end1 = nullptr;
    char* end2 = nullptr;
    const std::string a = o.blackout.substr(0, colon), b = colon == std::string::npos ? "" : o.blackout.substr(colon + 1);
    p.blackout_start_s = std::strtod(a.c_str(), &end1);
    p.blackout_s = std::strtod(b.c_str(), &end2);
    if (a.empty() || b.empty() || *end1 != '\0' || *end2 != '\0' || !(p.blackout_start_s >= 0) ||
        !(p.blackout_s > 0) || !std::isfinite(p.blackout_start_s + p.blackout_s)) {
      spdlog::error("--blackout: '{}' is not START_S:DURATION_S (seconds, start >= 0, duration > 0)", o.blackout);
      return 2;
    }
  }
  p.drop_every = o.drop_every;
  if (p.drop_every == 1) {
    spdlog::error("--drop-every: 1 would drop every frame (2 drops every other frame)");
    return 2;
  }
  const std::string scene_name = o.scene.empty() ? sc.scene : o.scene;
  if (scene_name != "room" && scene_name != "quality" && scene_name != "street") {
    spdlog::error("--scene: '{}' is not one of: room, quality, street", scene_name);
    return 2;
  }
  p.scale = o.scale > 0 ? o.scale : sc.scale;
  if (!(p.scale >= 0.05 && p.scale <= 20)) {
    spdlog::error("--scale: {} is not within [0.05, 20]", p.scale);
    return 2;
  }
  const drv::SyntheticScene scene = (scene_name == "quality"  ? drv::SyntheticScene::qualityRoom()
                                     : scene_name == "street" ? drv::SyntheticScene::street()
                                                              : drv::SyntheticScene::room())
                                        .scaled(static_cast<float>(p.scale));
  p.noise = sc.noise && !o.no_noise;
  p.noise_scale = sc.noise_scale;
  p.missing_blobs_per_frame = sc.missing_blobs_per_frame;
  p.color_delay_s = sc.color_delay_s;
  p.rolling_shutter_s = sc.rolling_shutter_s;
  p.exposure_s = sc.exposure_s;
  p.gain_variation = sc.gain_variation;
  if (o.handheld_camera) {
    // A consumer RGB-D camera's color stream indoors (Kinect v1 class),
    // where the configuration does not say otherwise.
    if (p.color_delay_s == 0.0) p.color_delay_s = 0.012;
    if (p.rolling_shutter_s == 0.0) p.rolling_shutter_s = 0.03;
    if (p.exposure_s == 0.0) p.exposure_s = 0.02;
    if (p.gain_variation == 0.0) p.gain_variation = 0.1;
  }
  Progress progress("rendering", static_cast<size_t>(p.frames));
  const auto status = drv::writeSyntheticSequence(o.out_dir, scene, p, makeParallelFor(config->runtime.threads),
                                                  [&](int done, int) { progress.update(static_cast<size_t>(done)); });
  if (!status) {
    spdlog::error("{}", status.message());
    return 1;
  }
  const drv::TrajectorySpeeds speeds = drv::trajectorySpeeds(drv::syntheticTrajectory(p));
  spdlog::info(
      "wrote {} frames at {} FPS of the synthetic {} scene (seed {}, {} trajectory, noise {}, scale {}) to {}; camera speed "
      "peak {:.2f} m/s and {:.0f} deg/s, mean {:.2f} m/s and {:.0f} deg/s",
      p.frames, p.fps, scene_name, p.seed, p.trajectory, p.noise ? "on" : "off", p.scale, o.out_dir, speeds.max_linear_mps,
      speeds.max_angular_dps, speeds.mean_linear_mps, speeds.mean_angular_dps);
  if (p.blackout_s > 0) spdlog::info("blackout from {:.2f} s for {:.2f} s", p.blackout_start_s, p.blackout_s);
  if (p.drop_every > 0) spdlog::info("one frame in {} left out of the lists", p.drop_every);
  if (drv::hasColorEffects(p)) {
    spdlog::info("color {:.0f} ms after depth, rolling shutter {:.0f} ms, exposure {:.0f} ms, gain +-{:.0f} %",
                 1000 * p.color_delay_s, 1000 * p.rolling_shutter_s, 1000 * p.exposure_s, 100 * p.gain_variation);
  }
  return 0;
}

int demoCommand(const std::string& out_dir, const std::string& config) {
  const std::string scene = (fs::path(out_dir) / "scene").string();
  SynthOptions so;
  so.out_dir = scene;
  so.config = config;
  if (const int rc = synthCommand(so); rc != 0) return rc;
  RunOptions ro;
  ro.dataset = scene;
  ro.config = config;
  ro.out_dir = out_dir;
  ro.overwrite = true;  // the demo maps its scene afresh
  return runCommand(ro);
}

int evalCommand(const EvalOptions& o) {
  bool did = false, failed = false;  // failed: something given could not be scored
  if (!o.traj.empty() || !o.gt_traj.empty()) {
    if (o.traj.empty() || o.gt_traj.empty()) {
      spdlog::error("trajectory evaluation needs both --traj and --gt-traj");
      return 2;
    }
    Trajectory est, gt;
    for (const auto& [path, out] : {std::pair{o.traj, &est}, {o.gt_traj, &gt}}) {
      auto text = drv::readTextFile(path);
      if (!text) {
        spdlog::error("{}", text.message());
        return 2;
      }
      auto parsed = drv::parseTumTrajectory(*text, path);
      if (!parsed) {
        spdlog::error("{}", parsed.message());
        return 2;
      }
      *out = parsed->poses;
    }
    bool scored = false;
    std::fputs(trajectoryMetricsText(est, gt, o.rpe_delta_s, &scored).c_str(), stdout);
    if (!scored) failed = true;
    did = true;
  }
  if (!o.mesh.empty() || !o.gt_mesh.empty()) {
    if (o.mesh.empty() || o.gt_mesh.empty()) {
      spdlog::error("mesh evaluation needs both --mesh and --gt-mesh");
      return 2;
    }
    auto rec = drv::readPly(o.mesh);
    auto gt = drv::readPly(o.gt_mesh);
    if (!rec || !gt) {
      spdlog::error("{}", !rec ? rec.message() : gt.message());
      return 2;
    }
    alg::MeshMetricsParams mp;
    mp.samples = o.samples;
    std::unique_ptr<alg::ObservedBy> observed;
    if (!o.observed_from.empty()) {
      auto ds = drv::Dataset::open(o.observed_from);
      if (!ds) {
        spdlog::error("{}", ds.message());
        return 2;
      }
      observed = std::make_unique<alg::ObservedBy>(
          alg::ObservedBy{(*ds)->camera(), (*ds)->groundTruth(), 10.0, (*ds)->sensorGrazingCos()});
    }
    const auto m = alg::computeMeshMetrics(*rec, *gt, mp, observed.get(), makeParallelFor(0));
    std::fputs(meshMetricsText(m, mp, observed.get()).c_str(), stdout);
    if (m.reconstruction_samples == 0 || m.ground_truth_samples == 0) failed = true;
    did = true;
  }
  if (!did) {
    spdlog::error("nothing to evaluate: give --traj/--gt-traj and/or --mesh/--gt-mesh");
    return 2;
  }
  if (failed) {
    spdlog::error("evaluation: nothing could be scored for at least one of the inputs (see n/a above)");
    return 1;
  }
  return 0;
}

#ifndef HXMAP_HAVE_DDS
int echoCommand(const EchoOptions&) {
  spdlog::error(
      "echo: this hxmap was built without Cyclone DDS (apt install cyclonedds-dev cyclonedds-tools, then "
      "configure and build again)");
  return 2;
}
#endif

drv::RigCalibration rigCalibration(const HxmapConfig& c) {
  const RigConfig& g = c.rig;
  drv::RigCalibration cal;
  cal.color = {g.color_fx,
               g.color_fy,
               g.color_cx,
               g.color_cy,
               g.color_width,
               g.color_height,
               {g.color_k1, g.color_k2, g.color_p1, g.color_p2, g.color_k3}};
  cal.depth = {g.depth_fx,
               g.depth_fy,
               g.depth_cx,
               g.depth_cy,
               g.depth_width,
               g.depth_height,
               {g.depth_k1, g.depth_k2, g.depth_p1, g.depth_p2, g.depth_k3}};
  const Eigen::Quaterniond q(g.depth_to_color_qw, g.depth_to_color_qx, g.depth_to_color_qy, g.depth_to_color_qz);
  cal.T_color_depth.linear() = q.normalized().toRotationMatrix();
  cal.T_color_depth.translation() = Eigen::Vector3d(g.depth_to_color_tx, g.depth_to_color_ty, g.depth_to_color_tz);
  cal.depth_scale = g.depth_scale;
  cal.registered = g.registered;
  cal.max_depth_m = g.max_depth_m;
  return cal;
}

int configCommand(const std::string& config) {
  auto c = config.empty() ? Expected<HxmapConfig>(HxmapConfig{}) : loadConfig(config);
  if (!c) {
    spdlog::error("{}", c.message());
    return 2;
  }
  std::fputs(dumpConfig(*c).c_str(), stdout);
  return 0;
}

RealtimeOptions realtimeOptions(const HxmapConfig& c, double fps) {
  RealtimeOptions ro;
  ro.fps = fps;
  ro.refine_workers = c.runtime.refine_workers;
  ro.background_nice = c.runtime.background_nice;
  ro.loop_parallel = makeParallelFor(c.runtime.threads);
  ro.scheduler.margin_ms = c.runtime.deadline_margin_ms;
  ro.scheduler.shed_after_periods = c.runtime.shed_after_periods;
  return ro;
}

FrontendParams frontendParams(const HxmapConfig& c) {
  FrontendParams fp;
  fp.preprocess = c.preprocess;
  fp.tsdf = c.tsdf;
  fp.raycast = c.raycast;
  fp.tracking = c.tracking;
  fp.relocalization = c.relocalization;
  fp.quality = c.quality;
  fp.quality_enabled = c.quality_enabled;
  fp.refine = c.refine;
  fp.refine.enabled = c.refine.enabled && c.quality_enabled;
  fp.feedback = c.feedback;
  fp.loop_closure = c.loop_closure;
  fp.resume_relocalize_frames = c.runtime.resume_relocalize_frames;
  fp.resume_new_map_otherwise = c.runtime.resume_otherwise == "new_map";
  fp.odometry_bias << 0.0, c.eval.odometry_bias_deg * M_PI / 180.0, 0.0, c.eval.odometry_bias_m, 0.0, 0.0;
  return fp;
}

int runReportingExceptions(const std::function<int()>& command) {
  try {
    return command();
  } catch (const std::exception& e) {
    spdlog::error("internal error, please report it: {}", e.what());
  } catch (...) {
    spdlog::error("internal error, please report it: an exception of unknown type");
  }
  return 1;
}

}  // namespace hxmap::rt
