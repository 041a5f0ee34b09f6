// The scheduler under load: a recording played in real time on both cores,
// alternately as configured and with a CPU-burning background job beside it
// (fixed slices, resubmitted as soon as one ends or is shed). Prints each
// run's deadline misses, drops, rate, frontend and arrival-to-pose times,
// background work admitted and shed, and ATE, then the medians per mode.
//
//   bench_shedding [dataset_dir] [--runs N] [--fps F] [--burn-ms MS] [--burn-threads T] [--config FILE]
//
// The default dataset is the whole TUM fr1/xyz at 30 FPS, two runs per mode,
// two burner threads of 30 ms slices (about three times the slack a frame
// leaves at 30 FPS).
#include <algorithm>
#include <cstdlib>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "burn_load.hpp"
#include "commands.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/realtime/realtime.hpp"
#include "parallel.hpp"
#include "quality_room_sequence.hpp"
#include "test_data.hpp"

using namespace hxmap;
using namespace hxmap::rt;

namespace {

struct RunFigures {
  double misses = 0, drops = 0, fps = 0, fe_p50 = 0, fe_p99 = 0, lat_p50 = 0, lat_p99 = 0;
  double jobs_made = 0, jobs_done = 0, jobs_shed = 0, burn_slices = 0, ate_cm = 0;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

void printRow(const std::string& label, const RunFigures& f, size_t frames) {
  fmt::print(
      "  {:<10} misses {:>3g}/{}  drops {:>3g}  {:5.1f} FPS  frontend p50 {:5.2f} p99 {:5.2f} ms  "
      "latency p50 {:5.2f} p99 {:5.2f} ms  refine jobs {:.0f} made, {:.0f} done, {:.0f} shed  burn slices {:.0f}  "
      "ATE {:.2f} cm\n",
      label, f.misses, frames, f.drops, f.fps, f.fe_p50, f.fe_p99, f.lat_p50, f.lat_p99, f.jobs_made, f.jobs_done,
      f.jobs_shed, f.burn_slices, f.ate_cm);
}

}  // namespace

int main(int argc, char** argv) {
  std::string dir = test::sharedData("tum/rgbd_dataset_freiburg1_xyz"), config_path;
  int runs = 2, burn_threads = 2;
  double fps = 30, burn_ms = 30;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool has_value = i + 1 < argc;
    if (a == "--runs" && has_value) {
      runs = std::atoi(argv[++i]);
    } else if (a == "--fps" && has_value) {
      fps = std::atof(argv[++i]);
    } else if (a == "--burn-ms" && has_value) {
      burn_ms = std::atof(argv[++i]);
    } else if (a == "--burn-threads" && has_value) {
      burn_threads = std::atoi(argv[++i]);
    } else if (a == "--config" && has_value) {
      config_path = argv[++i];
    } else if (!a.empty() && a[0] != '-') {
      dir = a;
    } else {
      fmt::print(stderr, "unknown or incomplete argument '{}'\n", a);
      return 2;
    }
  }
  if (runs < 1 || fps <= 0 || burn_ms <= 0 || burn_threads < 1) {
    fmt::print(stderr, "--runs, --fps, --burn-ms and --burn-threads must be positive\n");
    return 2;
  }
  HxmapConfig config;
  if (!config_path.empty()) {
    auto c = loadConfig(config_path);
    if (!c) {
      fmt::print(stderr, "{}\n", c.message());
      return 2;
    }
    config = *c;
  }
  test::BenchSequence sequence;
  if (!test::loadDatasetSequence(dir, sequence) || sequence.frames.empty()) return 1;
  const std::vector<RgbdFrame>& frames = sequence.frames;
  const Trajectory& gt = sequence.ground_truth;
  Eigen::Isometry3d T_world_cam0 = Eigen::Isometry3d::Identity();
  if (!gt.empty()) (void)alg::interpolatePose(gt, frames[0].stamp_ns, 200'000'000, T_world_cam0);
  fmt::print("{}: {} frames at {:.0f} FPS; {} run(s) per mode, alternating; burner: {} thread(s) of {:.0f} ms slices\n",
             dir, frames.size(), fps, runs, burn_threads, burn_ms);

  std::atomic<bool> stop{false};
  std::vector<RunFigures> plain, burned;
  for (int run = 0; run < runs; ++run) {
    for (const bool burn : {false, true}) {
      RealtimeOptions ro = realtimeOptions(config, fps);
      ro.status_interval_s = 0;
      test::BurnLoad load(burn_threads, burn_ms);
      if (burn) ro.extra_load = &load;
      Frontend frontend(sequence.camera, frontendParams(config),
                        makeParallelFor(config.runtime.threads));  // as hxmap run
      frontend.setInitialPose(T_world_cam0);
      const RealtimeStats s = runRealtime(frames, frontend, ro, stop);
      RunFigures f;
      f.misses = static_cast<double>(s.counters.deadline_misses);
      f.drops = static_cast<double>(s.counters.frames_dropped);
      f.fps = s.fps;
      f.fe_p50 = s.frontend_p50_ms;
      f.fe_p99 = s.frontend_p99_ms;
      f.lat_p50 = s.latency_p50_ms;
      f.lat_p99 = s.latency_p99_ms;
      f.jobs_made = static_cast<double>(s.refine_jobs_submitted);
      f.jobs_done = static_cast<double>(s.refine_jobs_completed);
      f.jobs_shed = static_cast<double>(s.refine_jobs_shed);
      f.burn_slices = static_cast<double>(load.slices());
      Trajectory estimate;
      for (const auto& r : s.results) {
        if (r.tracked) estimate.push_back({r.stamp_ns, r.T_world_cam});
      }
      if (!gt.empty()) f.ate_cm = alg::computeAte(estimate, gt).rmse_m * 100;
      printRow(fmt::format("{} #{}", burn ? "burner" : "plain", run + 1), f, frames.size());
      (burn ? burned : plain).push_back(f);
    }
  }
  auto medians = [](const std::vector<RunFigures>& v) {
    auto m = [&](double RunFigures::*field) {
      std::vector<double> x;
      for (const auto& f : v) x.push_back(f.*field);
      return median(x);
    };
    RunFigures r;
    for (double RunFigures::*field :
         {&RunFigures::misses, &RunFigures::drops, &RunFigures::fps, &RunFigures::fe_p50, &RunFigures::fe_p99,
          &RunFigures::lat_p50, &RunFigures::lat_p99, &RunFigures::jobs_made, &RunFigures::jobs_done,
          &RunFigures::jobs_shed, &RunFigures::burn_slices, &RunFigures::ate_cm}) {
      r.*field = m(field);
    }
    return r;
  };
  fmt::print("medians:\n");
  printRow("plain", medians(plain), frames.size());
  printRow("burner", medians(burned), frames.size());
  return 0;
}
