#include "hxmap/dds/publisher.hpp"

#include <algorithm>
#include <chrono>
#include <unordered_set>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <pthread.h>

namespace hxmap::rt::dds {

namespace {

int64_t nowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

uint64_t packRegion(const alg::RegionKey& r) { return alg::packBlockKey(r); }

constexpr const char* kMarkerNamespace = "hxmap_map";

// A region part as RViz draws it: every triangle's three corners in turn,
// with their colors.
MarkerMessage triangleListMarker(const alg::TriangleMesh& mesh, int32_t id, int64_t stamp_ns,
                                 const std::string& frame_id) {
  MarkerMessage m;
  m.stamp_ns = stamp_ns;
  m.frame_id = frame_id;
  m.ns = kMarkerNamespace;
  m.id = id;
  m.points.reserve(mesh.triangles.size() * 3);
  const bool colored = mesh.colors.size() == mesh.vertices.size();
  if (colored) m.colors.reserve(mesh.triangles.size() * 3);
  for (const auto& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      m.points.push_back(mesh.vertices[static_cast<size_t>(t[k])].cast<double>());
      if (colored) {
        const auto& c = mesh.colors[static_cast<size_t>(t[k])];
        m.colors.emplace_back(c[0] / 255.0f, c[1] / 255.0f, c[2] / 255.0f, 1.0f);
      }
    }
  }
  return m;
}

}  // namespace

struct Publisher::Work {
  enum Kind { kMap, kPath, kHealth, kFlush } kind = kMap;
  int64_t stamp_ns = 0;
  std::unique_ptr<alg::TsdfMap> snapshot;
  std::vector<alg::RegionKey> regions;
  /// Regions among `regions` with blocks out of memory, and those blocks
  /// (read into the snapshot on hx-publish).
  std::vector<std::pair<alg::RegionKey, std::vector<alg::BlockKey>>> elsewhere;
  PathMessage path;
  HealthMessage health;
  uint32_t flush_seq = 0;
};

Publisher::Publisher(const PublisherParams& params)
    : params_(params), ring_(static_cast<size_t>(std::max(params.queue_capacity, 2))) {}

Expected<std::unique_ptr<Publisher>> Publisher::start(const PublisherParams& params) {
  if (params.region_blocks < 1) return Error{fmt::format("dds.region_blocks: {} must be at least 1", params.region_blocks)};
  std::unique_ptr<Publisher> p(new Publisher(params));
  auto participant = Participant::create(params.domain_id);
  if (!participant) return participant.error();
  p->participant_ = std::move(*participant);
  for (Topic t : kAllTopics) {
    auto w = Writer::create(p->participant_, topicType(t), topicName(t, params.topic_prefix), topicQos(t));
    if (!w) return w.error();
    p->writers_.push_back(std::move(*w));
  }
  if (!params.base_frame_id.empty()) {
    // The fixed part, once: transient local, so late joiners get it too.
    const std::vector<TransformMessage> fixed{{0, params.base_frame_id, params.child_frame_id, params.T_base_cam}};
    const TfWire tf(fixed);  // points into `fixed`
    if (auto s = p->writers_[static_cast<size_t>(Topic::kTfStatic)].write(&tf.wire); !s) return Error{s.message()};
  }
  p->thread_ = std::thread([raw = p.get()] {
    pthread_setname_np(pthread_self(), "hx-publish");
    raw->run();
  });
  return p;
}

Publisher::~Publisher() {
  stop_.store(true, std::memory_order_release);
  work_seq_.fetch_add(1, std::memory_order_release);
  work_seq_.notify_one();
  if (thread_.joinable()) thread_.join();
}

uint32_t Publisher::matchedReaders(Topic topic) const { return writers_[static_cast<size_t>(topic)].matchedReaders(); }

bool Publisher::push(std::unique_ptr<Work> work, bool must) {
  while (!ring_.tryPush(std::move(work))) {
    if (!must) {
      ++items_dropped_;
      return false;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  work_seq_.fetch_add(1, std::memory_order_release);
  work_seq_.notify_one();
  return true;
}

void Publisher::snapshotMap(const alg::TsdfMap& map, int64_t stamp_ns, bool must) {
  const int64_t t0 = nowNs();
  auto work = std::make_unique<Work>();
  work->kind = Work::kMap;
  work->stamp_ns = stamp_ns;
  // DESIGN: under a memory budget a changed region may have blocks on disk:
  // meshed without them, it would go out without their surface and readers
  // would drop it. hx-publish reads those blocks from the block store
  // (read_elsewhere) into the update's copy before meshing. Without a
  // store to read, such a region waits (readers keep its last mesh) until
  // its blocks are back; the run's last flush brings every block back
  // first.
  std::vector<alg::RegionKey> changed = alg::changedRegions(map, map_revision_, params_.region_blocks);
  for (const auto& [key, r] : waiting_regions_) changed.push_back(r);
  {
    const std::lock_guard lock(retry_mutex_);
    changed.insert(changed.end(), retry_regions_.begin(), retry_regions_.end());
    retry_regions_.clear();
  }
  std::unordered_map<uint64_t, alg::RegionKey> still_waiting;
  std::unordered_set<uint64_t> taken;
  for (const auto& r : changed) {
    const uint64_t key = packRegion(r);
    if (!taken.insert(key).second) continue;
    std::vector<alg::BlockKey> out = alg::regionBlocksElsewhere(map, r, params_.region_blocks);
    if (out.empty()) {
      work->regions.push_back(r);
    } else if (params_.read_elsewhere) {
      work->regions.push_back(r);
      work->elsewhere.emplace_back(r, std::move(out));
    } else {
      still_waiting.emplace(key, r);
    }
  }
  region_waits_ += still_waiting.size();
  // Regions sent before that hold no block now (a loop closure rebuilt the
  // map without them) go out too: meshed empty, they are deleted.
  const std::vector<alg::RegionKey> occupied = alg::occupiedRegions(map, params_.region_blocks);
  std::unordered_set<uint64_t> live;
  for (const auto& r : occupied) live.insert(packRegion(r));
  std::vector<uint64_t> vanished;
  for (const auto& [key, r] : sent_regions_) {
    if (live.count(key) == 0) {
      vanished.push_back(key);
      work->regions.push_back(r);
    }
  }
  if (work->regions.empty()) {
    map_revision_ = map.revision();
    waiting_regions_ = std::move(still_waiting);
    return;
  }
  std::vector<alg::RegionKey> now_sent;
  for (const auto& r : work->regions) {
    if (live.count(packRegion(r)) != 0) now_sent.push_back(r);
  }
  work->snapshot = std::make_unique<alg::TsdfMap>(alg::copyRegions(map, work->regions, params_.region_blocks));
  snapshot_ms_total_ += static_cast<double>(nowNs() - t0) * 1e-6;
  const uint64_t revision = map.revision();
  // Refused: the regions stay marked and go out with the next update.
  if (!push(std::move(work), must)) return;
  map_revision_ = revision;
  waiting_regions_ = std::move(still_waiting);
  for (uint64_t key : vanished) sent_regions_.erase(key);
  for (const auto& r : now_sent) sent_regions_.emplace(packRegion(r), r);
}

void Publisher::queuePath(const Trajectory& trajectory, int64_t stamp_ns, bool must) {
  auto work = std::make_unique<Work>();
  work->kind = Work::kPath;
  work->path.stamp_ns = stamp_ns;
  work->path.frame_id = params_.frame_id;
  const size_t keep = params_.path_max_poses > 0 ? static_cast<size_t>(params_.path_max_poses) : trajectory.size();
  const size_t first = trajectory.size() > keep ? trajectory.size() - keep : 0;
  work->path.poses.assign(trajectory.begin() + static_cast<std::ptrdiff_t>(first), trajectory.end());
  for (auto& p : work->path.poses) p.stamp_ns += params_.stamp_offset_ns;
  push(std::move(work), must);
}

void Publisher::queueHealth(const RunCounters& counters, int64_t stamp_ns, bool must) {
  const int64_t now = nowNs();
  auto work = std::make_unique<Work>();
  work->kind = Work::kHealth;
  HealthMessage& h = work->health;
  h.stamp_ns = stamp_ns;
  h.frame_id = params_.frame_id;
  h.frames = frames_;
  h.frames_dropped = counters.frames_dropped;
  h.frames_lost = frames_lost_;
  h.deadline_misses = counters.deadline_misses;
  h.keyframes = keyframes_;
  h.refine_jobs_done = counters.refine_jobs_done;
  h.refine_jobs_shed = counters.refine_jobs_shed;
  h.messages_dropped = items_dropped_;
  const double period_s = static_cast<double>(now - last_health_ns_) * 1e-9;
  h.fps = last_health_ns_ > 0 && period_s > 0 ? static_cast<float>(static_cast<double>(period_frames_) / period_s) : 0.0f;
  h.latency_ms_p50 = static_cast<float>(median(period_latency_ms_));
  h.latency_ms_max = period_latency_ms_.empty()
                         ? 0.0f
                         : static_cast<float>(*std::max_element(period_latency_ms_.begin(), period_latency_ms_.end()));
  h.frontend_ms_p50 = static_cast<float>(median(period_frontend_ms_));
  period_latency_ms_.clear();
  period_frontend_ms_.clear();
  period_frames_ = 0;
  last_health_ns_ = now;
  push(std::move(work), must);
}

void Publisher::onFrame(const FrameResult& result, const alg::TsdfMap& map, const Trajectory& trajectory,
                        const RunCounters& counters) {
  const int64_t t0 = nowNs();
  ++frames_;
  ++period_frames_;
  if (!result.tracked) ++frames_lost_;
  if (result.keyframe) ++keyframes_;
  double frontend_ms = 0;
  for (double ms : result.stage_ms) frontend_ms += ms;
  period_frontend_ms_.push_back(frontend_ms);
  period_latency_ms_.push_back(counters.latency_ms);
  const int64_t stamp = result.stamp_ns + params_.stamp_offset_ns;
  if (result.tracked) {
    PoseMessage pose{stamp, params_.frame_id, result.T_world_cam};
    const PoseWire wire(pose);
    const Status s = writers_[static_cast<size_t>(Topic::kPose)].write(&wire.wire);
    if (s) {
      ++poses_;
    } else {
      recordError(s);
    }
    // map -> the base (or the camera itself), through odom when named:
    // map -> odom carries loop closures' corrections, odom -> base never
    // jumps at one (REP 105).
    const bool base = !params_.base_frame_id.empty();
    const std::string& moving = base ? params_.base_frame_id : params_.child_frame_id;
    const Eigen::Isometry3d T_world_moving =
        base ? result.T_world_cam * params_.T_base_cam.inverse() : result.T_world_cam;
    std::vector<TransformMessage> transforms;
    if (params_.odom_frame_id.empty()) {
      transforms.push_back({stamp, params_.frame_id, moving, T_world_moving});
    } else {
      transforms.push_back({stamp, params_.frame_id, params_.odom_frame_id, result.T_world_odom});
      transforms.push_back({stamp, params_.odom_frame_id, moving, result.T_world_odom.inverse() * T_world_moving});
    }
    const TfWire tf(transforms);  // points into `transforms`
    // nav_msgs/Odometry of the same chain's last link (odom -> base, or
    // map -> base without odom), with the velocity since the last frame.
    const TransformMessage& link = transforms.back();
    OdometryMessage odom{stamp, link.frame_id, link.child_frame_id, link.T_parent_child, {}, {}};
    if (last_odom_ && stamp > last_odom_->stamp_ns && last_odom_->frame_id == link.frame_id) {
      const double dt = static_cast<double>(stamp - last_odom_->stamp_ns) * 1e-9;
      const Eigen::Isometry3d step = last_odom_->T_parent_child.inverse() * link.T_parent_child;
      odom.linear = step.translation() / dt;
      const Eigen::AngleAxisd turn(step.linear());
      odom.angular = turn.axis() * turn.angle() / dt;
    }
    last_odom_ = odom;
    const OdometryWire odom_wire(odom);
    if (const Status so = writers_[static_cast<size_t>(Topic::kOdom)].write(&odom_wire.wire); !so) recordError(so);
    if (const Status st = writers_[static_cast<size_t>(Topic::kTf)].write(&tf.wire); st) {
      ++transforms_;
    } else {
      recordError(st);
    }
  }
  auto due = [&](int64_t& last, double period_s) {
    if (last != 0 && static_cast<double>(t0 - last) < period_s * 1e9) return false;
    last = t0;
    return true;
  };
  if (due(last_map_ns_, params_.map_period_s)) snapshotMap(map, stamp, false);
  if (due(last_path_ns_, params_.trajectory_period_s)) queuePath(trajectory, stamp, false);
  if (last_health_ns_ == 0) last_health_ns_ = t0;
  if (static_cast<double>(t0 - last_health_ns_) >= params_.health_period_s * 1e9) queueHealth(counters, stamp, false);
  // Bounded on long runs: the figures cover the last 50k to 100k frames.
  if (frame_cost_ms_.size() >= 100000) frame_cost_ms_.erase(frame_cost_ms_.begin(), frame_cost_ms_.begin() + 50000);
  frame_cost_ms_.push_back(static_cast<double>(nowNs() - t0) * 1e-6);
}

void Publisher::flush(const alg::TsdfMap& map, const Trajectory& trajectory, const RunCounters& counters) {
  const int64_t stamp = trajectory.empty() ? 0 : trajectory.back().stamp_ns + params_.stamp_offset_ns;
  snapshotMap(map, stamp, true);
  queuePath(trajectory, stamp, true);
  queueHealth(counters, stamp, true);
  auto work = std::make_unique<Work>();
  work->kind = Work::kFlush;
  work->flush_seq = ++flush_count_;
  push(std::move(work), true);
  for (uint32_t seen = flushed_seq_.load(std::memory_order_acquire); seen < flush_count_;
       seen = flushed_seq_.load(std::memory_order_acquire)) {
    flushed_seq_.wait(seen, std::memory_order_acquire);
  }
  // Written is not delivered: a process that exits after a flush would take
  // the last map update (large, in fragments) and poses still unacknowledged
  // with it. Wait for the reliable readers, bounded.
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(params_.flush_ack_timeout_s);
  for (const Writer& w : writers_) {
    const double left = std::chrono::duration<double>(end - std::chrono::steady_clock::now()).count();
    if (left <= 0 || !w.waitForAcks(left)) {
      ++ack_timeouts_;
      break;
    }
  }
}

void Publisher::run() {
  for (;;) {
    const uint32_t seq = work_seq_.load(std::memory_order_acquire);
    std::unique_ptr<Work> work;
    bool any = false;
    while (ring_.tryPop(work)) {
      any = true;
      process(*work);
    }
    if (any) resendMapToNewReaders();
    if (!any) {
      if (stop_.load(std::memory_order_acquire)) return;
      work_seq_.wait(seq, std::memory_order_acquire);
    }
  }
}

void Publisher::process(Work& work) {
  switch (work.kind) {
    case Work::kMap: {
      const int64_t t0 = nowNs();
      std::vector<MarkerMessage> markers;
      std::unordered_set<uint64_t> incomplete;
      for (const auto& [r, keys] : work.elsewhere) {
        const size_t unread = alg::readBlocksInto(*work.snapshot, keys, params_.read_elsewhere);
        blocks_read_elsewhere_.fetch_add(keys.size() - unread, std::memory_order_relaxed);
        if (unread > 0) incomplete.insert(packRegion(r));  // taken back since the update, or unreadable
      }
      for (const alg::RegionKey& r : work.regions) {
        if (incomplete.count(packRegion(r)) == 0) {
          writeRegion(*work.snapshot, r, work.stamp_ns, markers);
        } else {
          region_retries_.fetch_add(1, std::memory_order_relaxed);
          const std::lock_guard lock(retry_mutex_);
          retry_regions_.push_back(r);  // readers keep its last mesh meanwhile
        }
      }
      if (!markers.empty()) writeMarkers(markers);
      writeCloud(work.stamp_ns);
      map_updates_.fetch_add(1, std::memory_order_relaxed);
      mesh_ms_total_.store(mesh_ms_total_.load(std::memory_order_relaxed) + static_cast<double>(nowNs() - t0) * 1e-6,
                           std::memory_order_relaxed);
      break;
    }
    case Work::kPath: {
      const PathWire wire(work.path);
      const Status s = writers_[static_cast<size_t>(Topic::kTrajectory)].write(&wire.wire);
      if (s) paths_.fetch_add(1, std::memory_order_relaxed);
      else recordError(s);
      break;
    }
    case Work::kHealth: {
      const HealthWire wire(work.health);
      const Status s = writers_[static_cast<size_t>(Topic::kHealth)].write(&wire.wire);
      if (s) health_.fetch_add(1, std::memory_order_relaxed);
      else recordError(s);
      break;
    }
    case Work::kFlush:
      flushed_seq_.store(work.flush_seq, std::memory_order_release);
      flushed_seq_.notify_all();
      break;
  }
}

void Publisher::writeRegion(const alg::TsdfMap& snapshot, const alg::RegionKey& region, int64_t stamp_ns,
                            std::vector<MarkerMessage>& markers) {
  const alg::TriangleMesh mesh = alg::regionMesh(snapshot, region, params_.region_blocks, params_.mesh);
  const std::vector<alg::TriangleMesh> parts =
      alg::splitMesh(mesh, static_cast<size_t>(std::max(params_.max_triangles_per_chunk, 1)));
  RegionState& state = regions_[packRegion(region)];
  const size_t n = std::min<size_t>(parts.size(), 65535);
  if (n == 0 && state.parts == 0) return;  // no surface before or now: nothing to tell
  ++state.revision;
  MapChunkMessage m;
  m.stamp_ns = stamp_ns;
  m.frame_id = params_.frame_id;
  m.region = region;
  m.parts = static_cast<uint16_t>(n);
  m.revision = state.revision;
  m.region_size_m = snapshot.blockSize() * static_cast<float>(params_.region_blocks);
  Writer& writer = writers_[static_cast<size_t>(Topic::kMapChunks)];
  // Parts the region no longer has are sent empty, so a reader drops them.
  const size_t count = std::max<size_t>(n, state.parts);
  for (size_t i = 0; i < count; ++i) {
    m.part = static_cast<uint16_t>(i);
    m.vertices.clear();
    m.colors.clear();
    m.triangles.clear();
    if (i < n) {
      const alg::TriangleMesh& p = parts[i];
      m.vertices.reserve(p.vertices.size() * 3);
      for (const auto& v : p.vertices) m.vertices.insert(m.vertices.end(), {v.x(), v.y(), v.z()});
      if (p.colors.size() == p.vertices.size()) {
        m.colors.reserve(p.colors.size() * 3);
        for (const auto& c : p.colors) m.colors.insert(m.colors.end(), {c[0], c[1], c[2]});
      }
      m.triangles.reserve(p.triangles.size() * 3);
      for (const auto& t : p.triangles) {
        m.triangles.insert(m.triangles.end(), {static_cast<uint32_t>(t.x()), static_cast<uint32_t>(t.y()),
                                               static_cast<uint32_t>(t.z())});
      }
    }
    const MapChunkWire wire(m);
    const Status s = writer.write(&wire.wire);
    if (!s) {
      recordError(s);
      continue;
    }
    chunks_.fetch_add(1, std::memory_order_relaxed);
    chunk_bytes_.fetch_add(m.payloadBytes(), std::memory_order_relaxed);
  }
  // The same parts as markers, with a DELETE for each part the region no
  // longer has.
  while (state.marker_ids.size() < count) state.marker_ids.push_back(next_marker_id_++);
  for (size_t i = 0; i < count; ++i) {
    if (i < n) {
      markers.push_back(triangleListMarker(parts[i], state.marker_ids[i], stamp_ns, params_.frame_id));
    } else {
      MarkerMessage gone;
      gone.stamp_ns = stamp_ns;
      gone.frame_id = params_.frame_id;
      gone.ns = kMarkerNamespace;
      gone.id = state.marker_ids[i];
      gone.action = MarkerMessage::kDelete;
      markers.push_back(std::move(gone));
    }
  }
  state.meshes.assign(parts.begin(), parts.begin() + static_cast<std::ptrdiff_t>(n));
  state.parts = static_cast<uint16_t>(n);
  last_map_stamp_ns_ = stamp_ns;
  regions_written_.fetch_add(1, std::memory_order_relaxed);
}

void Publisher::writeMarkers(const std::vector<MarkerMessage>& markers) {
  const MarkerArrayWire wire(markers);
  const Status s = writers_[static_cast<size_t>(Topic::kMap)].write(&wire.wire);
  if (!s) {
    // A reader too slow for the writer's patience missed an increment:
    // everyone gets the whole map again (with the next work item).
    recordError(s);
    resend_all_ = true;
    return;
  }
  size_t bytes = 0;
  for (const auto& m : markers) bytes += m.payloadBytes();
  marker_arrays_.fetch_add(1, std::memory_order_relaxed);
  marker_bytes_.fetch_add(bytes, std::memory_order_relaxed);
}

void Publisher::writeCloud(int64_t stamp_ns) {
  PointCloudMessage cloud;
  cloud.stamp_ns = stamp_ns;
  cloud.frame_id = params_.frame_id;
  for (const auto& [key, state] : regions_) {
    for (const alg::TriangleMesh& mesh : state.meshes) {
      cloud.points.insert(cloud.points.end(), mesh.vertices.begin(), mesh.vertices.end());
      if (mesh.colors.size() == mesh.vertices.size()) {
        for (const auto& c : mesh.colors) cloud.colors.push_back({c[0], c[1], c[2]});
      } else {
        cloud.colors.insert(cloud.colors.end(), mesh.vertices.size(), {255, 255, 255});
      }
    }
  }
  const PointCloudWire wire(cloud);
  const Status s = writers_[static_cast<size_t>(Topic::kMapCloud)].write(&wire.wire);
  if (!s) {
    recordError(s);
    return;
  }
  clouds_.fetch_add(1, std::memory_order_relaxed);
  cloud_bytes_.fetch_add(cloud.payloadBytes(), std::memory_order_relaxed);
  last_cloud_points_.store(cloud.points.size(), std::memory_order_relaxed);
}

void Publisher::resendMapToNewReaders() {
  const uint32_t total = writers_[static_cast<size_t>(Topic::kMap)].matchedReadersTotal();
  if (total <= map_readers_seen_ && !resend_all_) return;
  map_readers_seen_ = total;
  resend_all_ = false;
  std::vector<MarkerMessage> markers;
  for (const auto& [key, state] : regions_) {
    for (size_t i = 0; i < state.meshes.size(); ++i) {
      markers.push_back(triangleListMarker(state.meshes[i], state.marker_ids[i], last_map_stamp_ns_, params_.frame_id));
    }
  }
  if (markers.empty()) return;
  writeMarkers(markers);
  map_resends_.fetch_add(1, std::memory_order_relaxed);
}

void Publisher::recordError(const Status& s) {
  write_errors_.fetch_add(1, std::memory_order_relaxed);
  std::lock_guard<std::mutex> lock(error_mutex_);
  if (last_error_ != s.message()) spdlog::warn("{}", s.message());
  last_error_ = s.message();
}

PublisherStats Publisher::stats() const {
  PublisherStats s;
  s.poses = poses_;
  s.transforms = transforms_;
  s.paths = paths_.load();
  s.health = health_.load();
  s.map_updates = map_updates_.load();
  s.regions = regions_written_.load();
  s.region_waits = region_waits_;
  {
    const std::lock_guard lock(retry_mutex_);
    s.regions_waiting = waiting_regions_.size() + retry_regions_.size();
  }
  s.blocks_read_elsewhere = blocks_read_elsewhere_.load(std::memory_order_relaxed);
  s.region_retries = region_retries_.load(std::memory_order_relaxed);
  s.chunks = chunks_.load();
  s.chunk_bytes = chunk_bytes_.load();
  s.marker_arrays = marker_arrays_.load();
  s.marker_bytes = marker_bytes_.load();
  s.map_resends = map_resends_.load();
  s.clouds = clouds_.load();
  s.cloud_bytes = cloud_bytes_.load();
  s.last_cloud_points = last_cloud_points_.load();
  s.ack_timeouts = ack_timeouts_;
  s.items_dropped = items_dropped_;
  s.write_errors = write_errors_.load();
  {
    std::lock_guard<std::mutex> lock(error_mutex_);
    s.last_error = last_error_;
  }
  s.frame_cost_p50_ms = median(frame_cost_ms_);
  s.frame_cost_max_ms = frame_cost_ms_.empty() ? 0 : *std::max_element(frame_cost_ms_.begin(), frame_cost_ms_.end());
  s.snapshot_ms_total = snapshot_ms_total_;
  s.mesh_ms_total = mesh_ms_total_.load();
  return s;
}

}  // namespace hxmap::rt::dds
