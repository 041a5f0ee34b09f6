// `hxmap echo` and the DDS publisher's configuration (built with HXMAP_WITH_DDS).
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstdio>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "dds_glue.hpp"
#include "hxmap/dds/entity.hpp"
#include "hxmap/dds/messages.hpp"
#include "hxmap/geometry/se3.hpp"
#include "stop_signals.hpp"

namespace hxmap::rt {

Expected<uint32_t> ddsDomain(int configured) {
  if (configured >= 0) return static_cast<uint32_t>(configured);
  const char* env = std::getenv("ROS_DOMAIN_ID");
  if (env == nullptr || *env == '\0') return 0u;
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(env, &end, 10);
  if (errno != 0 || *end != '\0' || v < 0 || v > 232) {
    return Error{fmt::format("ROS_DOMAIN_ID: '{}' is not a DDS domain id (an integer in [0, 232]); set it right, "
                             "or set dds.domain_id in the configuration",
                             env)};
  }
  return static_cast<uint32_t>(v);
}

Expected<dds::PublisherParams> publisherParams(const HxmapConfig& c) {
  auto domain = ddsDomain(c.dds.domain_id);
  if (!domain) return domain.error();
  dds::PublisherParams p;
  p.domain_id = *domain;
  p.topic_prefix = c.dds.topic_prefix;
  p.frame_id = c.dds.frame_id;
  p.child_frame_id = c.dds.child_frame_id;
  p.base_frame_id = c.dds.base_frame_id;
  p.odom_frame_id = c.dds.odom_frame_id;
  p.T_base_cam = alg::mountedOptical(
      {c.dds.base_to_camera_x_m, c.dds.base_to_camera_y_m, c.dds.base_to_camera_z_m},
      {c.dds.base_to_camera_roll_deg, c.dds.base_to_camera_pitch_deg, c.dds.base_to_camera_yaw_deg});
  p.map_period_s = c.dds.map_period_s;
  p.trajectory_period_s = c.dds.trajectory_period_s;
  p.path_max_poses = c.dds.path_max_poses;
  p.health_period_s = c.dds.health_period_s;
  p.region_blocks = c.dds.region_blocks;
  p.max_triangles_per_chunk = c.dds.max_triangles_per_chunk;
  p.queue_capacity = c.dds.queue_capacity;
  p.mesh = c.mesh;
  return p;
}

std::string publisherStatsText(const dds::PublisherStats& s, double wall_s) {
  return fmt::format(
             "dds: poses {}, transforms {}, trajectories {}, health {}, map updates {} ({} region meshes, {} chunks, "
             "{:.2f} "
             "MiB, "
             "{:.1f} KiB/s over {:.1f} s), work items dropped {}, write errors {}\n"
             "  map as MarkerArray: {} samples, {:.2f} MiB, {} whole-map resends to readers that joined; as "
             "PointCloud2: {} "
             "samples, {:.2f} MiB; "
             "final data not acknowledged by every reliable reader in time: {} times\n"
             "  publishing cost on the frontend thread: p50 {:.3f} ms, max {:.2f} ms per frame (region copies {:.1f} "
             "ms in "
             "all); "
             "meshing and writing chunks {:.1f} ms in all on hx-publish\n",
             s.poses, s.transforms, s.paths, s.health, s.map_updates, s.regions, s.chunks,
             static_cast<double>(s.chunk_bytes) / (1 << 20),
             wall_s > 0 ? static_cast<double>(s.chunk_bytes) / 1024.0 / wall_s : 0.0, wall_s, s.items_dropped,
             s.write_errors, s.marker_arrays, static_cast<double>(s.marker_bytes) / (1 << 20), s.map_resends, s.clouds,
             static_cast<double>(s.cloud_bytes) / (1 << 20), s.ack_timeouts, s.frame_cost_p50_ms, s.frame_cost_max_ms,
             s.snapshot_ms_total, s.mesh_ms_total) +
         (s.region_waits > 0
              ? fmt::format("  region updates held back until their blocks were back in memory: {}\n", s.region_waits)
              : std::string()) +
         (s.blocks_read_elsewhere + s.region_retries > 0
              ? fmt::format("  blocks out of memory read from the block store for region meshes: {}; region updates "
                            "sent again because a block had come back meanwhile: {}\n",
                            s.blocks_read_elsewhere, s.region_retries)
              : std::string());
}

int echoCommand(const EchoOptions& o) {
  HxmapConfig c;
  if (!o.config.empty()) {
    auto loaded = loadConfig(o.config);
    if (!loaded) {
      spdlog::error("{}", loaded.message());
      return 2;
    }
    c = *loaded;
  }
  const auto topic = dds::topicFromString(o.topic);
  if (!topic) {
    spdlog::error("{}", topic.message());
    return 2;
  }
  const auto resolved = ddsDomain(o.domain_id >= 0 ? o.domain_id : c.dds.domain_id);
  if (!resolved) {
    spdlog::error("{}", resolved.message());
    return 2;
  }
  const uint32_t domain = *resolved;
  const std::string prefix = o.prefix.empty() ? c.dds.topic_prefix : o.prefix;
  auto participant = dds::Participant::create(domain);
  if (!participant) {
    spdlog::error("{}", participant.message());
    return 1;
  }
  const std::string name = dds::topicName(*topic, prefix);
  auto reader = dds::Reader::create(*participant, dds::topicType(*topic), name, dds::topicQos(*topic));
  if (!reader) {
    spdlog::error("{}", reader.message());
    return 1;
  }
  spdlog::info("echo: {} in domain {} (Ctrl-C to stop)", name, domain);
  StopSignals signals;
  const auto t0 = std::chrono::steady_clock::now();
  int printed = 0, bad = 0;
  auto print = [&](const void* sample, const dds_sample_info_t&) {
    std::string line;
    switch (*topic) {
      case dds::Topic::kPose:
        line = dds::describe(dds::fromWire(*static_cast<const geometry_msgs_msg_dds__PoseStamped_*>(sample)));
        break;
      case dds::Topic::kOdom:
        line = dds::describe(dds::fromWire(*static_cast<const nav_msgs_msg_dds__Odometry_*>(sample)));
        break;
      case dds::Topic::kTrajectory:
        line = dds::describe(dds::fromWire(*static_cast<const nav_msgs_msg_dds__Path_*>(sample)));
        break;
      case dds::Topic::kMap: {
        const auto markers = dds::fromWire(*static_cast<const visualization_msgs_msg_dds__MarkerArray_*>(sample));
        if (!markers) {
          spdlog::warn("{}: {}", name, markers.message());
          ++bad;
          return;
        }
        line = dds::describe(*markers);
        break;
      }
      case dds::Topic::kMapCloud: {
        const auto cloud = dds::fromWire(*static_cast<const sensor_msgs_msg_dds__PointCloud2_*>(sample));
        if (!cloud) {
          spdlog::warn("{}: {}", name, cloud.message());
          ++bad;
          return;
        }
        line = dds::describe(*cloud);
        break;
      }
      case dds::Topic::kMapChunks: {
        const auto chunk = dds::fromWire(*static_cast<const hxmap_msgs_msg_dds__MapChunk_*>(sample));
        if (!chunk) {
          spdlog::warn("{}: {}", name, chunk.message());
          ++bad;
          return;
        }
        line = dds::describe(*chunk);
        break;
      }
      case dds::Topic::kHealth:
        line = dds::describe(dds::fromWire(*static_cast<const hxmap_msgs_msg_dds__Health_*>(sample)));
        break;
      case dds::Topic::kTf:
      case dds::Topic::kTfStatic:
        for (const auto& t : dds::fromWire(*static_cast<const tf2_msgs_msg_dds__TFMessage_*>(sample))) {
          if (!line.empty()) line += '\n';
          line += dds::describe(t);
        }
        break;
    }
    if (o.count > 0 && printed >= o.count) return;
    std::fputs((line + "\n").c_str(), stdout);
    std::fflush(stdout);
    ++printed;
  };
  while (!g_stop.load() && (o.count <= 0 || printed < o.count)) {
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (o.timeout_s > 0 && elapsed >= o.timeout_s) {
      spdlog::error("echo: {}: {} of {} messages within {:.1f} s", name, printed, o.count, o.timeout_s);
      return 1;
    }
    auto ready = reader->wait(0.2);
    if (!ready) {
      spdlog::error("{}", ready.message());
      return 1;
    }
    if (!*ready) continue;
    auto taken = reader->take(print);
    if (!taken) {
      spdlog::error("{}", taken.message());
      return 1;
    }
  }
  return bad > 0 ? 1 : 0;
}

}  // namespace hxmap::rt
