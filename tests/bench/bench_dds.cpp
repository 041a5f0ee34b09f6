// DDS publishing benchmark, on loopback (set CYCLONEDDS_URI to
// config/cyclonedds-loopback.xml; the program does when it is unset).
//
// 1. Pose latency: this process publishes poses through the Publisher at
//    100 Hz; a subscriber in a separate process (this program, re-run as
//    a child) takes each one as soon as its waitset wakes and measures
//    receive time minus the writer's source timestamp (same host clock).
//    Prints p50/p99 and the publisher's cost per pose on the calling thread.
// 2. A recording (default: the shared TUM slice) played at its recorded rate through the runtime
//    threads twice in this process: without DDS and with the publisher
//    (default dds: settings; a subscriber process reads every topic). Map
//    update bandwidth per second of playback, publishing cost per frame on
//    the frontend thread and on hx-publish, and the frontend time of both
//    runs side by side.
//
//   bench_dds [tum_dir] [config.yaml]
// Prints numbers; asserts nothing.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "commands.hpp"
#include "dds_glue.hpp"
#include "dds_loopback.hpp"
#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dds/publisher.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/realtime/realtime.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "quality_room_sequence.hpp"
#include "test_data.hpp"

using namespace hxmap;
using namespace hxmap::rt;

namespace {

constexpr uint32_t kDomain = 78;

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

// Child: reads `count` poses (or every topic for `seconds`) and prints figures.
int subscriber(const std::string& prefix, const std::string& mode, int count) {
  auto participant = dds::Participant::create(kDomain);
  if (!participant) {
    fmt::print(stderr, "{}\n", participant.message());
    return 1;
  }
  if (mode == "latency") {
    auto reader = dds::Reader::create(*participant, dds::topicType(dds::Topic::kPose),
                                      dds::topicName(dds::Topic::kPose, prefix), dds::topicQos(dds::Topic::kPose));
    if (!reader) return 1;
    std::vector<double> latency_us;
    const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (static_cast<int>(latency_us.size()) < count && std::chrono::steady_clock::now() < end) {
      auto ready = reader->wait(0.5);
      if (!ready || !*ready) continue;
      const dds_time_t now = dds_time();
      (void)reader->take([&](const void*, const dds_sample_info_t& info) {
        latency_us.push_back(static_cast<double>(now - info.source_timestamp) * 1e-3);
      });
    }
    fmt::print("{} {:.1f} {:.1f} {:.1f}\n", latency_us.size(), percentile(latency_us, 0.5), percentile(latency_us, 0.99),
               percentile(latency_us, 1.0));
    return 0;
  }
  if (mode == "late") {
    // Joins late: seconds until the markers it holds make `count` triangles.
    const auto t0 = std::chrono::steady_clock::now();
    auto reader = dds::Reader::create(*participant, dds::topicType(dds::Topic::kMap),
                                      dds::topicName(dds::Topic::kMap, prefix), dds::topicQos(dds::Topic::kMap));
    if (!reader) return 1;
    std::map<int32_t, size_t> triangles;  // by marker id
    size_t total = 0;
    while (total != static_cast<size_t>(count) && std::chrono::steady_clock::now() < t0 + std::chrono::seconds(60)) {
      (void)reader->wait(0.05);
      (void)reader->take([&](const void* s, const dds_sample_info_t&) {
        const auto& a = *static_cast<const visualization_msgs_msg_dds__MarkerArray_*>(s);
        for (uint32_t i = 0; i < a.markers._length; ++i) {
          const auto& m = a.markers._buffer[i];
          if (m.action == 2)
            triangles.erase(m.id);
          else
            triangles[m.id] = m.points._length / 3;
        }
      });
      total = 0;
      for (const auto& [id, n] : triangles) total += n;
    }
    fmt::print("{} {:.3f}\n", total, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    return 0;
  }
  // mode "all": keep every topic drained for `count` seconds, count bytes.
  std::vector<dds::Reader> readers;
  for (dds::Topic t :
       {dds::Topic::kPose, dds::Topic::kTrajectory, dds::Topic::kMapChunks, dds::Topic::kHealth, dds::Topic::kMap}) {
    auto r = dds::Reader::create(*participant, dds::topicType(t), dds::topicName(t, prefix), dds::topicQos(t));
    if (!r) return 1;
    readers.push_back(std::move(*r));
  }
  size_t chunks = 0, chunk_bytes = 0, poses = 0, arrays = 0, marker_bytes = 0;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(count);
  while (std::chrono::steady_clock::now() < end) {
    for (size_t i = 0; i < readers.size(); ++i) {
      (void)readers[i].take([&](const void* s, const dds_sample_info_t&) {
        if (i == 0) ++poses;
        if (i == 2) {
          const auto& w = *static_cast<const hxmap_msgs_msg_dds__MapChunk_*>(s);
          ++chunks;
          chunk_bytes += w.vertices._length * 4 + w.colors._length + w.triangles._length * 4;
        }
        if (i == 4) {
          const auto& a = *static_cast<const visualization_msgs_msg_dds__MarkerArray_*>(s);
          ++arrays;
          for (uint32_t k = 0; k < a.markers._length; ++k) {
            marker_bytes += a.markers._buffer[k].points._length * 24 + a.markers._buffer[k].colors._length * 16;
          }
        }
      });
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  fmt::print("{} {} {} {} {}\n", poses, chunks, chunk_bytes, arrays, marker_bytes);
  return 0;
}

struct Child {
  pid_t pid = -1;
  FILE* out = nullptr;
};

Child spawn(const char* self, const std::string& prefix, const std::string& mode, int count) {
  int fds[2];
  if (pipe(fds) != 0) return {};
  const pid_t pid = fork();
  if (pid == 0) {
    dup2(fds[1], 1);
    close(fds[0]);
    close(fds[1]);
    const std::string n = std::to_string(count);
    execl(self, self, "--child", prefix.c_str(), mode.c_str(), n.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  close(fds[1]);
  return {pid, fdopen(fds[0], "r")};
}

std::string finish(Child& c) {
  std::string out;
  char buf[256];
  while (c.out != nullptr && fgets(buf, sizeof buf, c.out) != nullptr) out += buf;
  if (c.out != nullptr) fclose(c.out);
  int status = 0;
  if (c.pid > 0) waitpid(c.pid, &status, 0);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 5 && std::string(argv[1]) == "--child") return subscriber(argv[2], argv[3], std::atoi(argv[4]));
  setenv("CYCLONEDDS_URI", kLoopbackDdsUri, 0);
  const std::string tum_dir = argc > 1 ? argv[1] : std::string(HXMAP_SHARED_DATA) + "/tum/rgbd_dataset_freiburg1_xyz_first40";
  HxmapConfig config;
  if (argc > 2) {
    auto c = loadConfig(argv[2]);
    if (!c) {
      fmt::print(stderr, "{}\n", c.message());
      return 2;
    }
    config = *c;
  }
  config.dds.domain_id = static_cast<int>(kDomain);

  // 1. Pose latency to another process.
  {
    const std::string prefix = fmt::format("hxbench_{}_lat", getpid());
    dds::PublisherParams p = *publisherParams(config);
    p.topic_prefix = prefix;
    p.map_period_s = p.trajectory_period_s = p.health_period_s = 3600;
    auto pub = dds::Publisher::start(p);
    if (!pub) {
      fmt::print(stderr, "{}\n", pub.message());
      return 1;
    }
    const int n = 1000;
    Child child = spawn(argv[0], prefix, "latency", n);
    if (!waitFor([&] { return (*pub)->matchedReaders(dds::Topic::kPose) > 0; }, 30)) {
      fmt::print(stderr, "no subscriber matched within 30 s\n");
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // let the child's waitset settle
    alg::TsdfMap map(config.tsdf);
    Trajectory trajectory;  // not published here
    for (int k = 0; k < n + 50; ++k) {  // a few extra for best-effort losses
      FrameResult r;
      r.stamp_ns = int64_t{k} * 10'000'000;
      r.tracked = true;
      r.T_world_cam.translation() = Eigen::Vector3d(0.001 * k, 0, 1);
      (*pub)->onFrame(r, map, trajectory, RunCounters{});
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    const std::string out = finish(child);
    size_t received = 0;
    double p50 = 0, p99 = 0, mx = 0;
    std::sscanf(out.c_str(), "%zu %lf %lf %lf", &received, &p50, &p99, &mx);
    const auto s = (*pub)->stats();
    fmt::print("pose latency over loopback to another process ({} of {} poses at 100 Hz received):\n"
               "  p50 {:.1f} us, p99 {:.1f} us, max {:.1f} us\n"
               "  publisher cost per pose on the calling thread: p50 {:.1f} us, max {:.1f} us\n",
               received, n + 50, p50, p99, mx, s.frame_cost_p50_ms * 1e3, s.frame_cost_max_ms * 1e3);
  }

  // 2. The recording at its recorded rate, without and with publishing.
  test::BenchSequence sequence;
  if (!test::loadDatasetSequence(tum_dir, sequence) || sequence.frames.empty()) return 1;
  const std::vector<RgbdFrame>& frames = sequence.frames;
  const double sequence_s = static_cast<double>(frames.back().stamp_ns - frames.front().stamp_ns) * 1e-9;
  Eigen::Isometry3d T0 = Eigen::Isometry3d::Identity();
  if (!sequence.ground_truth.empty())
    (void)alg::interpolatePose(sequence.ground_truth, frames[0].stamp_ns, 200'000'000, T0);
  std::atomic<bool> stop{false};
  RealtimeOptions ro;
  ro.status_interval_s = 0;
  ro.refine_workers = config.runtime.refine_workers;
  auto frontendMs = [](const RealtimeStats& s) { return s.frontend_p50_ms; };
  fmt::print("{}: {} frames, {:.2f} s at the recorded rate\n", tum_dir, frames.size(), sequence_s);
  for (int run = 0; run < 2; ++run) {
    Frontend frontend(sequence.camera, frontendParams(config));
    frontend.setInitialPose(T0);
    if (run == 0) {
      const RealtimeStats s = runRealtime(frames, frontend, ro, stop);
      fmt::print("  without DDS: frontend p50 {:.2f} ms, p99 {:.2f} ms; latency arrival->pose p50 {:.2f} ms\n",
                 frontendMs(s), s.frontend_p99_ms, s.latency_p50_ms);
      continue;
    }
    const std::string prefix = fmt::format("hxbench_{}_tum", getpid());
    dds::PublisherParams p = *publisherParams(config);
    p.topic_prefix = prefix;
    auto pub = dds::Publisher::start(p);
    if (!pub) {
      fmt::print(stderr, "{}\n", pub.message());
      return 1;
    }
    Child child = spawn(argv[0], prefix, "all", static_cast<int>(sequence_s) + 8);
    waitFor([&] { return (*pub)->matchedReaders(dds::Topic::kMapChunks) > 0; }, 30);
    RealtimeOptions with = ro;
    with.on_frame = [&](const FrameResult& r, const Frontend& f, const RunCounters& c) {
      (*pub)->onFrame(r, f.map(), f.trajectory(), c);
    };
    const auto t0 = std::chrono::steady_clock::now();
    const RealtimeStats s = runRealtime(frames, frontend, with, stop);
    (*pub)->flush(frontend.map(), frontend.trajectory(), RunCounters{});
    const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const auto ps = (*pub)->stats();
    const std::string out = finish(child);
    size_t poses = 0, chunks = 0, bytes = 0, arrays = 0, marker_bytes = 0;
    std::sscanf(out.c_str(), "%zu %zu %zu %zu %zu", &poses, &chunks, &bytes, &arrays, &marker_bytes);
    // A late joiner of the MarkerArray map, while the publisher keeps
    // working (a flush every 100 ms stands in for the frames of a live run).
    const size_t map_triangles = alg::extractMesh(frontend.map(), p.mesh).triangles.size();
    Child late = spawn(argv[0], prefix, "late", static_cast<int>(map_triangles));
    std::atomic<bool> pumping{true};
    std::thread pump([&] {
      while (pumping.load()) {
        (*pub)->flush(frontend.map(), frontend.trajectory(), RunCounters{});
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
    });
    const std::string late_out = finish(late);
    pumping.store(false);
    pump.join();
    size_t late_triangles = 0;
    double late_s = 0;
    std::sscanf(late_out.c_str(), "%zu %lf", &late_triangles, &late_s);
    const auto ps2 = (*pub)->stats();
    fmt::print(
        "  with DDS:    frontend p50 {:.2f} ms, p99 {:.2f} ms; latency arrival->pose p50 {:.2f} ms\n"
        "  map updates: {} ({} region meshes, {} chunks), {:.1f} KiB in all = {:.1f} KiB/s over {:.2f} s of "
        "playback and final flush (map period {:.1f} s)\n"
        "  subscriber process received {} poses, {} chunks, {:.1f} KiB of chunk payload\n"
        "  map as MarkerArray: {} updates, {:.1f} KiB in all = {:.1f} KiB/s, {:.1f} KiB per update "
        "(received {} arrays, {:.1f} KiB)\n"
        "  late joiner: {} of {} triangles after {:.2f} s ({} whole-map resends, the last {:.1f} KiB)\n"
        "  publishing cost per frame: frontend thread p50 {:.3f} ms, max {:.2f} ms (region copies {:.2f} ms/frame "
        "on average); hx-publish meshing+writing {:.2f} ms/frame on average\n",
        frontendMs(s), s.frontend_p99_ms, s.latency_p50_ms, ps.map_updates, ps.regions, ps.chunks,
        static_cast<double>(ps.chunk_bytes) / 1024, static_cast<double>(ps.chunk_bytes) / 1024 / wall_s, wall_s,
        p.map_period_s, poses, chunks, static_cast<double>(bytes) / 1024, ps.marker_arrays,
        static_cast<double>(ps.marker_bytes) / 1024, static_cast<double>(ps.marker_bytes) / 1024 / wall_s,
        static_cast<double>(ps.marker_bytes) / 1024 / std::max<double>(1.0, static_cast<double>(ps.marker_arrays)),
        arrays, static_cast<double>(marker_bytes) / 1024, late_triangles, map_triangles, late_s, ps2.map_resends,
        static_cast<double>(ps2.marker_bytes - ps.marker_bytes) / 1024 /
            std::max<double>(1.0, static_cast<double>(ps2.map_resends - ps.map_resends)),
        ps.frame_cost_p50_ms, ps.frame_cost_max_ms, ps.snapshot_ms_total / static_cast<double>(frames.size()),
        ps.mesh_ms_total / static_cast<double>(frames.size()));
    fmt::print(
        "  map as PointCloud2 (the whole map in each update): {} samples, {:.1f} KiB in all = {:.1f} KiB/s, "
        "{:.1f} KiB per sample, the last {} points\n",
        ps.clouds, static_cast<double>(ps.cloud_bytes) / 1024, static_cast<double>(ps.cloud_bytes) / 1024 / wall_s,
        static_cast<double>(ps.cloud_bytes) / 1024 / std::max<double>(1.0, static_cast<double>(ps.clouds)),
        ps.last_cloud_points);
  }
  return 0;
}
