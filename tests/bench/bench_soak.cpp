// A long flight under a memory budget: laps around the synthetic room
// scaled up (3x: 12 m by 9 m, 7.8 m high; about 1.1 m/s), rendered and
// mapped frame by frame with tracking, refinement and loop closure off (their
// own memory is not what is measured here). Per 1000 frames: voxels
// resident, the process's RSS, blocks out of memory, moved out and brought
// back, the store's bytes on disk, and the frontend's p50/p99; then the same
// flight without a budget.
//
//   bench_soak [FRAMES=10000] [BUDGET_MIB=256] [VOXEL_M=0.02] [WIDTH=320] [SCALE=3]
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "bench_stats.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/mapfile/block_store.hpp"

using namespace hxmap;

namespace {

double rssMib() {
  std::ifstream statm("/proc/self/statm");
  long pages = 0, resident = 0;
  statm >> pages >> resident;
  return static_cast<double>(resident) * static_cast<double>(::sysconf(_SC_PAGESIZE)) / (1 << 20);
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

void fly(int frames, double budget_mib, double voxel_m, int width, double scale) {
  const int height = width * 3 / 4;
  const double f = 525.0 * width / 640.0;
  const alg::PinholeCamera cam{f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height, {0, 0, 0, 0, 0}};
  drv::SyntheticParams sp;
  sp.frames = frames;
  sp.camera = cam;
  sp.scale = scale;
  const Trajectory truth = drv::syntheticTrajectory(sp);
  const drv::SyntheticScene scene = drv::SyntheticScene::room().scaled(static_cast<float>(scale));
  rt::FrontendParams params;
  params.tsdf.voxel_size_m = voxel_m;
  params.tsdf.truncation_m = 4 * voxel_m;
  params.tsdf.max_resident_mib = budget_mib;
  params.refine.enabled = false;
  params.loop_closure.enabled = false;
  rt::Frontend fe(cam, params);
  fe.setInitialPose(truth.front().T_world_cam);
  std::unique_ptr<drv::BlockStore> store;
  if (budget_mib > 0) {
    auto s = drv::BlockStore::create(std::filesystem::temp_directory_path().string());
    if (!s) {
      std::fprintf(stderr, "%s\n", s.message().c_str());
      std::exit(1);
    }
    store = std::move(*s);
    fe.setBlockBacking(store.get());
  }
  std::printf(
      "\n%s: %d frames, %dx%d, %.0f cm voxels, room scaled %gx\n",
      budget_mib > 0 ? ("budget " + std::to_string(static_cast<int>(budget_mib)) + " MiB").c_str() : "no budget",
      frames, width, height, 100 * voxel_m, scale);
  std::printf("%7s %10s %8s %9s %9s %9s %9s %8s %8s %6s\n", "frames", "path m", "voxels", "RSS MiB", "out blks",
              "moved out", "back", "disk MiB", "p50 ms", "p99 ms");
  std::vector<double> window;
  double path_m = 0;
  size_t lost = 0;
  for (int i = 0; i < frames; ++i) {
    drv::SyntheticParams p = sp;
    auto r = drv::renderFrame(scene, cam, truth[static_cast<size_t>(i)].T_world_cam, p, i);
    RgbdFrame frame;
    frame.rgb = r.rgb;
    frame.depth = r.depth;
    frame.stamp_ns = truth[static_cast<size_t>(i)].stamp_ns;
    frame.seq = static_cast<uint64_t>(i);
    const auto t0 = bench::Clock::now();
    const rt::FrameResult res = fe.process(frame);
    window.push_back(bench::ms(t0, bench::Clock::now()));
    lost += !res.tracked;
    if (i > 0) {
      path_m += (truth[static_cast<size_t>(i)].T_world_cam.translation() -
                 truth[static_cast<size_t>(i - 1)].T_world_cam.translation())
                    .norm();
    }
    if ((i + 1) % 1000 == 0 || i + 1 == frames) {
      const rt::MemoryCounters m = fe.memoryCounters();
      const drv::BlockStoreStats s = store ? store->stats() : drv::BlockStoreStats{};
      std::printf("%7d %10.0f %8.1f %9.1f %9zu %9llu %9llu %8.1f %8.1f %6.1f\n", i + 1, path_m,
                  static_cast<double>(fe.map().memory().bytes) / (1 << 20), rssMib(), fe.map().blocksElsewhere().size(),
                  static_cast<unsigned long long>(m.evicted), static_cast<unsigned long long>(m.taken_back),
                  static_cast<double>(s.file_bytes) / (1 << 20), bench::median(window), percentile(window, 0.99));
      std::fflush(stdout);
      window.clear();
    }
  }
  std::printf("lost frames %zu; voxels column: MiB resident\n", lost);
}

}  // namespace

int main(int argc, char** argv) {
  const int frames = argc > 1 ? std::atoi(argv[1]) : 10000;
  const double budget = argc > 2 ? std::atof(argv[2]) : 256;
  const double voxel = argc > 3 ? std::atof(argv[3]) : 0.02;
  const int width = argc > 4 ? std::atoi(argv[4]) : 320;
  const double scale = argc > 5 ? std::atof(argv[5]) : 3;
  if (budget > 0) fly(frames, budget, voxel, width, scale);
  fly(frames, 0, voxel, width, scale);
  return 0;
}
