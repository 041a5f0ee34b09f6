// A long flight under a memory budget: by default end to end of the
// synthetic street (160 m) and back, about 1 m/s on average, rendered and
// mapped frame by frame at the true poses (POSES=given: the map, not
// tracking, is what is measured; POSES=tracked tracks them) with refinement
// and loop closure off (their own memory is not what is measured here); or
// laps around the synthetic room scaled up (SCENE a number: the scale). Per 1000 frames:
// voxels resident, the process's RSS, blocks out of memory, moved out and
// brought back, the store's bytes on disk, and the frontend's p50/p99. Then
// the same flight without a budget, and whether the two agree: moving blocks
// out and back is lossless, so both runs track the same poses and, once
// every block is back, hold the same map (compared voxel by voxel, the
// mesh with it). Each flight runs in a process of its own, so that neither
// sees the other's memory.
//
//   bench_soak [FRAMES=10000] [BUDGET_MIB=256] [VOXEL_M=0.02] [WIDTH=320] [SCENE=street] [POSES=given]
//              [budget-only]     (the flight under the budget alone; compare its map hash by hand)
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

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

/// What a flight leaves to compare: the map's fingerprint with every block
/// in memory and the poses it tracked.
struct FlightResult {
  uint64_t map_hash = 0;
  uint64_t blocks = 0;
  std::vector<Eigen::Vector3d> positions;
};

/// FNV-1a over every block's voxels (geometry, color, statistics) in key
/// order: equal for maps that hold the same values in the same blocks.
uint64_t mapHash(const alg::TsdfMap& map) {
  std::vector<std::pair<uint64_t, size_t>> order;
  order.reserve(map.blockCount());
  for (size_t i = 0; i < map.blockCount(); ++i) order.emplace_back(alg::packBlockKey(map.key(i)), i);
  std::sort(order.begin(), order.end());
  uint64_t h = 1469598103934665603ULL;
  auto mix = [&h](const void* data, size_t n) {
    const auto* b = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ULL;
  };
  for (const auto& [key, i] : order) {
    const alg::VoxelBlock& block = map.block(i);
    mix(&key, sizeof key);
    mix(block.geo, sizeof block.geo);
    mix(block.color, sizeof block.color);
    mix(block.stats, sizeof block.stats);
  }
  return h;
}

struct Flight {
  int frames = 10000;
  double budget_mib = 256, voxel_m = 0.02;
  int width = 320;
  std::string scene = "street";
  bool given_poses = true;
};

FlightResult fly(const Flight& flight, double budget_mib) {
  const int frames = flight.frames, width = flight.width;
  const double voxel_m = flight.voxel_m;
  const std::string& scene_name = flight.scene;
  const int height = width * 3 / 4;
  const double f = 525.0 * width / 640.0;
  const alg::PinholeCamera cam{f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height, {0, 0, 0, 0, 0}};
  drv::SyntheticParams sp;
  sp.frames = frames;
  sp.camera = cam;
  const bool street = scene_name == "street";
  if (street) {
    sp.trajectory = "street";
  } else {
    sp.scale = std::atof(scene_name.c_str());
  }
  const Trajectory truth = drv::syntheticTrajectory(sp);
  const drv::SyntheticScene scene =
      street ? drv::SyntheticScene::street() : drv::SyntheticScene::room().scaled(static_cast<float>(sp.scale));
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
  const std::string what = street ? std::string("street") : "room scaled " + scene_name + "x";
  std::printf(
      "\n%s: %d frames, %dx%d, %.0f cm voxels, %s, %s poses\n",
      budget_mib > 0 ? ("budget " + std::to_string(static_cast<int>(budget_mib)) + " MiB").c_str() : "no budget",
      frames, width, height, 100 * voxel_m, what.c_str(), flight.given_poses ? "true" : "tracked");
  std::printf("%7s %10s %8s %9s %9s %9s %9s %8s %8s %8s %6s\n", "frames", "path m", "voxels", "RSS MiB", "out blks",
              "moved out", "back", "disk MiB", "held MiB", "p50 ms", "p99 ms");
  FlightResult result;
  std::vector<double> window;
  double path_m = 0;
  size_t lost = 0;
  for (int i = 0; i < frames; ++i) {
    auto r = drv::renderFrame(scene, cam, truth[static_cast<size_t>(i)].T_world_cam, sp, i);
    RgbdFrame frame;
    frame.rgb = r.rgb;
    frame.depth = r.depth;
    frame.stamp_ns = truth[static_cast<size_t>(i)].stamp_ns;
    frame.seq = static_cast<uint64_t>(i);
    const auto t0 = bench::Clock::now();
    const Eigen::Isometry3d& T_true = truth[static_cast<size_t>(i)].T_world_cam;
    const rt::FrameResult res = fe.process(frame, flight.given_poses ? &T_true : nullptr);
    window.push_back(bench::ms(t0, bench::Clock::now()));
    lost += !res.tracked;
    result.positions.push_back(res.T_world_cam.translation());
    if (i > 0) {
      path_m += (truth[static_cast<size_t>(i)].T_world_cam.translation() -
                 truth[static_cast<size_t>(i - 1)].T_world_cam.translation())
                    .norm();
    }
    if ((i + 1) % 1000 == 0 || i + 1 == frames) {
      const rt::MemoryCounters m = fe.memoryCounters();
      const drv::BlockStoreStats s = store ? store->stats() : drv::BlockStoreStats{};
      // What the budget's bookkeeping holds in memory: the store's queue,
      // read-ahead cache and index, and the map's set of blocks out.
      const double held = static_cast<double>(s.queued_bytes + s.read_ahead_bytes + s.index_bytes +
                                              fe.map().blocksElsewhere().memoryBytes()) /
                          (1 << 20);
      std::printf("%7d %10.0f %8.1f %9.1f %9zu %9llu %9llu %8.1f %8.1f %8.1f %6.1f\n", i + 1, path_m,
                  static_cast<double>(fe.map().memory().bytes) / (1 << 20), rssMib(), fe.map().blocksElsewhere().size(),
                  static_cast<unsigned long long>(m.evicted), static_cast<unsigned long long>(m.taken_back),
                  static_cast<double>(s.file_bytes) / (1 << 20), held, bench::median(window), percentile(window, 0.99));
      std::fflush(stdout);
      window.clear();
    }
  }
  std::printf(
      "lost frames %zu; frames that ended over the budget %llu; voxels: MiB resident; held: the store's queue, "
      "read-ahead and index and the map's set of blocks out\n",
      lost, static_cast<unsigned long long>(fe.memoryCounters().frames_over_budget));
  fe.restoreEvicted();
  result.blocks = fe.map().blockCount();
  result.map_hash = mapHash(fe.map());
  std::printf("every block back: %llu blocks, map hash %016llx\n", static_cast<unsigned long long>(result.blocks),
              static_cast<unsigned long long>(result.map_hash));
  std::fflush(stdout);
  return result;
}

/// fly() in a child process (its memory is its own: RSS is not what an
/// earlier flight left in the allocator); the result comes back through a
/// pipe.
FlightResult flyApart(const Flight& flight, double budget_mib) {
  int fds[2];
  if (::pipe(fds) != 0) {
    std::perror("pipe");
    std::exit(1);
  }
  const pid_t pid = ::fork();
  if (pid < 0) {
    std::perror("fork");
    std::exit(1);
  }
  if (pid == 0) {
    ::close(fds[0]);
    const FlightResult r = fly(flight, budget_mib);
    const uint64_t head[3] = {r.map_hash, r.blocks, r.positions.size()};
    bool ok = ::write(fds[1], head, sizeof head) == static_cast<ssize_t>(sizeof head);
    for (const Eigen::Vector3d& p : r.positions) {
      ok = ok && ::write(fds[1], p.data(), 3 * sizeof(double)) == static_cast<ssize_t>(3 * sizeof(double));
    }
    std::fflush(stdout);
    ::_exit(ok ? 0 : 1);
  }
  ::close(fds[1]);
  FlightResult r;
  auto readAll = [&](void* data, size_t n) {
    auto* b = static_cast<char*>(data);
    while (n > 0) {
      const ssize_t got = ::read(fds[0], b, n);
      if (got <= 0) return false;
      b += got;
      n -= static_cast<size_t>(got);
    }
    return true;
  };
  uint64_t head[3] = {0, 0, 0};
  bool ok = readAll(head, sizeof head);
  r.map_hash = head[0];
  r.blocks = head[1];
  r.positions.resize(ok ? head[2] : 0);
  for (Eigen::Vector3d& p : r.positions) ok = ok && readAll(p.data(), 3 * sizeof(double));
  ::close(fds[0]);
  int status = 0;
  ::waitpid(pid, &status, 0);
  if (!ok || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    std::fprintf(stderr, "the flight's process failed\n");
    std::exit(1);
  }
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  Flight f;
  if (argc > 1) f.frames = std::atoi(argv[1]);
  if (argc > 2) f.budget_mib = std::atof(argv[2]);
  if (argc > 3) f.voxel_m = std::atof(argv[3]);
  if (argc > 4) f.width = std::atoi(argv[4]);
  if (argc > 5) f.scene = argv[5];
  const std::string poses = argc > 6 ? argv[6] : "given";
  const bool budget_only = argc > 7 && std::string(argv[7]) == "budget-only";
  f.given_poses = poses == "given";
  if (f.frames < 1 || !(f.voxel_m > 0) || f.width < 64 || (f.scene != "street" && !(std::atof(f.scene.c_str()) > 0)) ||
      (poses != "given" && poses != "tracked")) {
    std::fprintf(stderr,
                 "usage: bench_soak [FRAMES=10000] [BUDGET_MIB=256] [VOXEL_M=0.02] [WIDTH=320] "
                 "[SCENE=street|ROOM_SCALE] [POSES=given|tracked] [budget-only]\n");
    return 2;
  }
  if (budget_only) return f.budget_mib > 0 ? (flyApart(f, f.budget_mib), 0) : 2;
  const FlightResult unbounded = flyApart(f, 0);
  if (f.budget_mib <= 0) return 0;
  const FlightResult bounded = flyApart(f, f.budget_mib);
  double max_pose_diff = 0;
  for (size_t i = 0; i < std::min(bounded.positions.size(), unbounded.positions.size()); ++i) {
    max_pose_diff = std::max(max_pose_diff, (bounded.positions[i] - unbounded.positions[i]).norm());
  }
  std::printf(
      "\nbudget against none: poses differ by at most %.3g mm; maps with every block back: %llu and %llu blocks, "
      "%s\n",
      1000 * max_pose_diff, static_cast<unsigned long long>(bounded.blocks),
      static_cast<unsigned long long>(unbounded.blocks),
      bounded.map_hash == unbounded.map_hash ? "identical voxel for voxel" : "DIFFERENT");
  return bounded.map_hash == unbounded.map_hash ? 0 : 1;
}
