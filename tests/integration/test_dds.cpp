// Cyclone DDS for real, on loopback (config/cyclonedds-loopback.xml): the
// publisher's topics read back by a second participant in this process and
// by `hxmap echo` in a separate process, a late joiner receiving the whole
// map, and clean errors. Each test process uses its own topic prefix, so
// tests running in parallel do not hear each other.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <thread>

#include <fmt/format.h>

#include "dds_loopback.hpp"
#include "hxmap/dds/entity.hpp"
#include "hxmap/dds/messages.hpp"
#include "hxmap/dds/publisher.hpp"
#include "hxmap/dds/type_hash.hpp"
#include "hxmap/geometry/se3.hpp"
#include "hxmap/mapfile/block_store.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "hxmap/tsdf/patch.hpp"

namespace hxmap::rt::dds {
namespace {

constexpr uint32_t kDomain = 77;

class Loopback : public ::testing::Environment {
 public:
  void SetUp() override {
    setenv("CYCLONEDDS_URI", kLoopbackDdsUri, 1);
  }
};
const auto* const kEnv = ::testing::AddGlobalTestEnvironment(new Loopback);

std::string prefix(const char* test) { return fmt::format("hxtest_{}_{}", getpid(), test); }

PublisherParams params(const std::string& prefix) {
  PublisherParams p;
  p.domain_id = kDomain;
  p.topic_prefix = prefix;
  p.map_period_s = 3600;  // map, trajectory and health only on flush()
  p.trajectory_period_s = 3600;
  p.health_period_s = 3600;
  p.region_blocks = 2;
  p.max_triangles_per_chunk = 300;  // several parts per region
  return p;
}

Eigen::Isometry3d poseAt(int k) {
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  T_world_cam.linear() = Eigen::AngleAxisd(0.1 * k, Eigen::Vector3d(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  T_world_cam.translation() = Eigen::Vector3d(0.01 * k, -0.2 + 0.003 * k, 1.5 - 0.02 * k);
  return T_world_cam;
}

FrameResult frame(int k) {
  FrameResult r;
  r.stamp_ns = 1'305'031'102'000'000'000 + int64_t{k} * 33'333'333;
  r.T_world_cam = poseAt(k);
  r.tracked = true;
  return r;
}

// A sphere fused through a patch (so its blocks are marked changed).
void addSphere(alg::TsdfMap& map, const Eigen::Vector3f& center, float radius) {
  alg::TsdfPatch patch;
  const float mu = map.truncation();
  const Eigen::Vector3i lo = map.voxelOf(center - Eigen::Vector3f::Constant(radius + mu));
  const Eigen::Vector3i hi = map.voxelOf(center + Eigen::Vector3f::Constant(radius + mu));
  for (int z = lo.z(); z <= hi.z(); ++z) {
    for (int y = lo.y(); y <= hi.y(); ++y) {
      for (int x = lo.x(); x <= hi.x(); ++x) {
        const Eigen::Vector3i g(x, y, z);
        const float d = (map.voxelCenter(g) - center).norm() - radius;
        if (std::abs(d) > mu) continue;
        alg::TsdfPatch::Entry e;
        e.voxel = g;
        e.sdf_m = d;
        e.weight = 1.0f;
        e.has_color = true;
        e.rgb[0] = static_cast<uint8_t>(40 + (x & 127));
        e.rgb[1] = 90;
        e.rgb[2] = static_cast<uint8_t>(200 - (z & 127));
        patch.entries.push_back(e);
      }
    }
  }
  alg::applyPatch(map, patch);
}

alg::TsdfParams tsdfParams() {
  alg::TsdfParams p;
  p.voxel_size_m = 0.02;
  p.truncation_m = 0.08;
  return p;
}

// The map the map tests publish: a large sphere across many regions and a
// small one (carved away or left out later) apart from it.
alg::TsdfMap twoSpheres() {
  alg::TsdfMap map(tsdfParams());
  addSphere(map, {0.05f, -0.07f, 0.11f}, 0.23f);
  addSphere(map, {0.9f, 0.1f, 0.4f}, 0.12f);
  return map;
}

// Free space observed around `center` (25 voxels a side): the surface
// there is carved away.
void carveAround(alg::TsdfMap& map, const Eigen::Vector3f& center) {
  alg::TsdfPatch carve;
  for (int z = -12; z <= 12; ++z) {
    for (int y = -12; y <= 12; ++y) {
      for (int x = -12; x <= 12; ++x) {
        alg::TsdfPatch::Entry e;
        e.voxel = map.voxelOf(center) + Eigen::Vector3i(x, y, z);
        int index = 0;
        if (map.blockOfVoxel(e.voxel, index) == nullptr) continue;
        e.sdf_m = map.truncation();
        e.weight = 1000.0f;
        carve.entries.push_back(e);
      }
    }
  }
  alg::applyPatch(map, carve);
}

// The map as a reader holds it: newest revision of every (region, part).
struct ReceivedMap {
  std::map<std::array<int, 4>, MapChunkMessage> parts;
  size_t bad = 0;
  void add(const hxmap_msgs_msg_dds__MapChunk_& w) {
    auto m = fromWire(w);
    if (!m) {
      ++bad;
      return;
    }
    const std::array<int, 4> key{m->region.x(), m->region.y(), m->region.z(), m->part};
    auto it = parts.find(key);
    if (it == parts.end() || it->second.revision <= m->revision) parts[key] = std::move(*m);
  }
  // Triangles and area of the parts each region currently has.
  std::pair<size_t, double> totals() const {
    size_t triangles = 0;
    double area = 0;
    for (const auto& entry : parts) {
      const auto& m = entry.second;  // clang 14 lets no lambda capture a structured binding
      if (m.part >= m.parts) continue;
      triangles += m.triangles.size() / 3;
      for (size_t t = 0; t < m.triangles.size(); t += 3) {
        auto v = [&](size_t i) {
          const size_t k = 3 * m.triangles[t + i];
          return Eigen::Vector3d(m.vertices[k], m.vertices[k + 1], m.vertices[k + 2]);
        };
        area += 0.5 * (v(1) - v(0)).cross(v(2) - v(0)).norm();
      }
    }
    return {triangles, area};
  }
};

size_t drainMap(Reader& reader, ReceivedMap& received) {
  auto n = reader.take([&](const void* s, const dds_sample_info_t&) {
    received.add(*static_cast<const hxmap_msgs_msg_dds__MapChunk_*>(s));
  });
  return n ? *n : 0;
}

// The map as RViz's MarkerArray display holds it: the newest marker per
// (ns, id), deleted ones gone.
struct ReceivedMarkers {
  std::map<std::pair<std::string, int32_t>, MarkerMessage> markers;
  size_t samples = 0, bad = 0, colorless = 0;
  void add(const visualization_msgs_msg_dds__MarkerArray_& w) {
    ++samples;
    auto array = fromWire(w);
    if (!array) {
      ++bad;
      return;
    }
    for (auto& m : *array) {
      const auto key = std::make_pair(m.ns, m.id);
      if (m.action == MarkerMessage::kDelete) {
        markers.erase(key);
        continue;
      }
      if (m.type != MarkerMessage::kTriangleList || m.frame_id != "map") ++bad;
      if (m.colors.size() != m.points.size()) ++colorless;
      markers[key] = std::move(m);
    }
  }
  std::pair<size_t, double> totals() const {
    size_t triangles = 0;
    double area = 0;
    for (const auto& [key, m] : markers) {
      triangles += m.points.size() / 3;
      for (size_t t = 0; t + 2 < m.points.size(); t += 3) {
        area += 0.5 * (m.points[t + 1] - m.points[t]).cross(m.points[t + 2] - m.points[t]).norm();
      }
    }
    return {triangles, area};
  }
};

size_t drainMarkers(Reader& reader, ReceivedMarkers& received) {
  auto n = reader.take([&](const void* s, const dds_sample_info_t&) {
    received.add(*static_cast<const visualization_msgs_msg_dds__MarkerArray_*>(s));
  });
  return n ? *n : 0;
}

// Takes markers until they make `triangles` triangles (20 s at most).
::testing::AssertionResult markersReach(Reader& reader, ReceivedMarkers& received, size_t triangles) {
  if (waitFor(
          [&] {
            drainMarkers(reader, received);
            return received.totals().first == triangles;
          },
          20)) {
    return ::testing::AssertionSuccess();
  }
  return ::testing::AssertionFailure() << received.totals().first << " of " << triangles << " triangles in "
                                       << received.samples << " MarkerArrays";
}

TEST(DdsMessages, WireRoundTripKeepsValues) {
  const PoseMessage pose{1'305'031'102'175'304'000, "map", poseAt(7)};
  const PoseMessage back = fromWire(PoseWire(pose).wire);
  EXPECT_EQ(back.stamp_ns, pose.stamp_ns);
  EXPECT_EQ(back.frame_id, "map");
  EXPECT_LT((back.T_world_cam.matrix() - pose.T_world_cam.matrix()).cwiseAbs().maxCoeff(), 1e-12);

  PathMessage path{42, "map", {{1, poseAt(1)}, {2, poseAt(2)}, {-1'500'000'000, poseAt(3)}}};
  const PathMessage path_back = fromWire(PathWire(path).wire);
  ASSERT_EQ(path_back.poses.size(), 3u);
  EXPECT_EQ(path_back.poses[2].stamp_ns, -1'500'000'000);  // negative stamps: floor seconds, positive nanoseconds
  EXPECT_LT((path_back.poses[1].T_world_cam.matrix() - poseAt(2).matrix()).cwiseAbs().maxCoeff(), 1e-12);

  MapChunkMessage chunk;
  chunk.region = {-3, 4, 0};
  chunk.part = 1;
  chunk.parts = 2;
  chunk.revision = 9;
  chunk.vertices = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  chunk.colors = {1, 2, 3, 4, 5, 6, 7, 8, 9};
  chunk.triangles = {0, 1, 2};
  auto chunk_back = fromWire(MapChunkWire(chunk).wire);
  ASSERT_TRUE(chunk_back) << chunk_back.message();
  EXPECT_EQ(chunk_back->region, chunk.region);
  EXPECT_EQ(chunk_back->vertices, chunk.vertices);
  EXPECT_EQ(chunk_back->colors, chunk.colors);
  EXPECT_EQ(chunk_back->triangles, chunk.triangles);
  EXPECT_EQ(chunk_back->payloadBytes(), 9 * 4 + 9 + 3 * 4u);

  // Inconsistent chunks are errors naming the chunk, not crashes.
  chunk.triangles = {0, 1, 3};
  auto bad = fromWire(MapChunkWire(chunk).wire);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.message().find("(-3, 4, 0) part 1"), std::string::npos) << bad.message();
  EXPECT_NE(bad.message().find("out of range"), std::string::npos) << bad.message();
  chunk.triangles = {0, 1};
  EXPECT_FALSE(fromWire(MapChunkWire(chunk).wire));
  chunk.triangles = {0, 1, 2};
  chunk.colors = {1, 2, 3};
  EXPECT_FALSE(fromWire(MapChunkWire(chunk).wire));

  EXPECT_EQ(topicName(Topic::kPose, "hxmap"), "rt/hxmap/pose");
  EXPECT_STREQ(topicType(Topic::kPose)->m_typename, "geometry_msgs::msg::dds_::PoseStamped_");
  EXPECT_STREQ(topicType(Topic::kTrajectory)->m_typename, "nav_msgs::msg::dds_::Path_");
  EXPECT_FALSE(topicFromString("poses"));
}

// Poses from the publisher to a reader with `reader_qos` in another
// participant: 19 of 20 frames (one lost frame publishes none), each exact.
void expectPosesReach(const std::string& pre, const TopicQos& reader_qos) {
  auto pub = Publisher::start(params(pre));
  ASSERT_TRUE(pub) << pub.message();
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  auto reader = Reader::create(*participant, topicType(Topic::kPose), topicName(Topic::kPose, pre), reader_qos);
  ASSERT_TRUE(reader) << reader.message();
  ASSERT_TRUE(waitFor([&] { return (*pub)->matchedReaders(Topic::kPose) > 0 && reader->matchedWriters() > 0; }, 20));

  alg::TsdfMap map(tsdfParams());
  Trajectory trajectory;
  std::map<int64_t, Eigen::Isometry3d> sent;
  for (int k = 0; k < 20; ++k) {
    FrameResult r = frame(k);
    if (k == 5) r.tracked = false;  // a lost frame publishes no pose
    else sent[r.stamp_ns] = r.T_world_cam;
    trajectory.push_back({r.stamp_ns, r.T_world_cam});
    (*pub)->onFrame(r, map, trajectory, RunCounters{});
  }
  std::map<int64_t, PoseMessage> received;
  ASSERT_TRUE(waitFor([&] {
    (void)reader->take([&](const void* s, const dds_sample_info_t&) {
      const PoseMessage m = fromWire(*static_cast<const geometry_msgs_msg_dds__PoseStamped_*>(s));
      received[m.stamp_ns] = m;
    });
    return received.size() >= sent.size();
  }, 20));
  // On loopback inside one process nothing is lost; each value is exact.
  ASSERT_EQ(received.size(), 19u);
  for (const auto& [stamp, m] : received) {
    ASSERT_TRUE(sent.count(stamp)) << stamp;
    EXPECT_EQ(m.frame_id, "map");
    EXPECT_LT((m.T_world_cam.matrix() - sent[stamp].matrix()).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_EQ((*pub)->stats().poses, 19u);
}

TEST(DdsLoopback, PosesReachABestEffortReader) { expectPosesReach(prefix("pose_be"), {false, false, 100}); }

// rclcpp's default subscription (and RViz's, Nav2's) is reliable and
// volatile; a best-effort writer does not match it (REP 2003: publishers
// are reliable so that both kinds of reader match). The reader keeps 100
// here because the test takes the samples only after all 20 are written.
TEST(DdsLoopback, PosesReachAReliableReaderAsRos2SubscribesByDefault) {
  EXPECT_TRUE(topicQos(Topic::kPose).reliable);
  expectPosesReach(prefix("pose_rel"), {true, false, 100});
}

TEST(DdsLoopback, LateJoinerReceivesTheWholeMapAndItsUpdates) {
  const std::string pre = prefix("map");
  auto pub = Publisher::start(params(pre));
  ASSERT_TRUE(pub) << pub.message();
  alg::TsdfMap map = twoSpheres();
  const Trajectory trajectory{{1, poseAt(0)}, {2, poseAt(1)}};
  (*pub)->flush(map, trajectory, RunCounters{});
  const alg::TriangleMesh full = alg::extractMesh(map, alg::MeshParams{});
  ASSERT_GT(full.triangles.size(), 2000u);
  const PublisherStats s1 = (*pub)->stats();
  EXPECT_GT(s1.chunks, s1.regions);  // some regions needed several parts
  EXPECT_EQ(s1.write_errors, 0u);

  // Joins after everything was written: transient-local delivers it.
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  auto reader = Reader::create(*participant, topicType(Topic::kMapChunks), topicName(Topic::kMapChunks, pre),
                               topicQos(Topic::kMapChunks));
  ASSERT_TRUE(reader) << reader.message();
  ReceivedMap received;
  ASSERT_TRUE(waitFor([&] {
    drainMap(*reader, received);
    return received.parts.size() >= s1.chunks;
  }, 20)) << received.parts.size() << " of " << s1.chunks << " chunks";
  EXPECT_EQ(received.bad, 0u);
  auto [triangles, area] = received.totals();
  EXPECT_EQ(triangles, full.triangles.size());
  EXPECT_NEAR(area, full.surfaceArea(), 1e-5 * full.surfaceArea());

  // The small sphere is carved away (free space observed there): its
  // regions lose their triangles and must say so.
  carveAround(map, {0.9f, 0.1f, 0.4f});
  (*pub)->flush(map, trajectory, RunCounters{});
  const alg::TriangleMesh carved = alg::extractMesh(map, alg::MeshParams{});
  ASSERT_LT(carved.triangles.size(), full.triangles.size());
  const PublisherStats s2 = (*pub)->stats();
  EXPECT_GT(s2.chunks, s1.chunks);
  // The reader that stayed sees the updates; a new one sees the new map only.
  ASSERT_TRUE(waitFor([&] {
    drainMap(*reader, received);
    return received.totals().first == carved.triangles.size();
  }, 20)) << received.totals().first << " vs " << carved.triangles.size();
  auto reader2 = Reader::create(*participant, topicType(Topic::kMapChunks), topicName(Topic::kMapChunks, pre),
                                topicQos(Topic::kMapChunks));
  ASSERT_TRUE(reader2) << reader2.message();
  ReceivedMap late;
  ASSERT_TRUE(waitFor([&] {
    drainMap(*reader2, late);
    return late.totals().first == carved.triangles.size() && late.parts.size() == received.parts.size();
  }, 20)) << late.totals().first << " vs " << carved.triangles.size();
  EXPECT_NEAR(late.totals().second, carved.surfaceArea(), 1e-5 * carved.surfaceArea());

  // Trajectory and health are transient-local too.
  auto path_reader = Reader::create(*participant, topicType(Topic::kTrajectory), topicName(Topic::kTrajectory, pre),
                                    topicQos(Topic::kTrajectory));
  ASSERT_TRUE(path_reader) << path_reader.message();
  PathMessage path;
  ASSERT_TRUE(waitFor([&] {
    (void)path_reader->take([&](const void* s, const dds_sample_info_t&) {
      path = fromWire(*static_cast<const nav_msgs_msg_dds__Path_*>(s));
    });
    return path.poses.size() == 2;
  }, 20));
  EXPECT_LT((path.poses[1].T_world_cam.matrix() - poseAt(1).matrix()).cwiseAbs().maxCoeff(), 1e-12);
}

// RViz's MarkerArray display (and any ROS 2 node) reads the map from a
// keyless topic, whose writer keeps one sample for late joiners: the
// publisher sends the whole map again when a reader joins.
TEST(DdsLoopback, ALateJoinerOfTheMarkerMapGetsTheWholeMapAndTheReadersThereFollowItsUpdates) {
  const std::string pre = prefix("markers");
  auto pub = Publisher::start(params(pre));
  ASSERT_TRUE(pub) << pub.message();
  alg::TsdfMap map = twoSpheres();
  const Trajectory trajectory{{1, poseAt(0)}, {2, poseAt(1)}};
  (*pub)->flush(map, trajectory, RunCounters{});
  const alg::TriangleMesh full = alg::extractMesh(map, alg::MeshParams{});
  const PublisherStats s1 = (*pub)->stats();
  EXPECT_EQ(s1.marker_arrays, 1u);  // one MarkerArray per update
  EXPECT_EQ(s1.map_resends, 0u);    // nobody was listening

  // Joins after the map was written; as soon as the publisher has seen it
  // (its next work item, here the next flush), the whole map is sent again.
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  auto reader =
      Reader::create(*participant, topicType(Topic::kMap), topicName(Topic::kMap, pre), topicQos(Topic::kMap));
  ASSERT_TRUE(reader) << reader.message();
  ASSERT_TRUE(waitFor([&] { return (*pub)->matchedReaders(Topic::kMap) == 1; }, 20));
  (*pub)->flush(map, trajectory, RunCounters{});
  ReceivedMarkers received;
  ASSERT_TRUE(markersReach(*reader, received, full.triangles.size()));
  EXPECT_EQ(received.bad, 0u);
  EXPECT_EQ(received.colorless, 0u);
  EXPECT_NEAR(received.totals().second, full.surfaceArea(), 1e-5 * full.surfaceArea());

  // The small sphere is carved away: the reader there sees its parts deleted.
  carveAround(map, {0.9f, 0.1f, 0.4f});
  (*pub)->flush(map, trajectory, RunCounters{});
  const alg::TriangleMesh carved = alg::extractMesh(map, alg::MeshParams{});
  ASSERT_LT(carved.triangles.size(), full.triangles.size());
  ASSERT_TRUE(markersReach(*reader, received, carved.triangles.size()));

  // A second late joiner gets the carved map, nothing of what was deleted.
  auto reader2 =
      Reader::create(*participant, topicType(Topic::kMap), topicName(Topic::kMap, pre), topicQos(Topic::kMap));
  ASSERT_TRUE(reader2) << reader2.message();
  ASSERT_TRUE(waitFor([&] { return (*pub)->matchedReaders(Topic::kMap) == 2; }, 20));
  (*pub)->flush(map, trajectory, RunCounters{});
  ReceivedMarkers late;
  ASSERT_TRUE(markersReach(*reader2, late, carved.triangles.size()));
  EXPECT_NEAR(late.totals().second, carved.surfaceArea(), 1e-5 * carved.surfaceArea());
  EXPECT_EQ(late.markers.size(), received.markers.size());
  EXPECT_EQ((*pub)->stats().map_resends, 2u);
  EXPECT_EQ((*pub)->stats().write_errors, 0u);
}

// The map as a PointCloud2 (RViz's PointCloud2 display, PCL): every
// region part's vertices with their colors, the whole map in each sample.
TEST(DdsLoopback, ALateJoinerOfTheCloudGetsEveryRegionsSurfacePoints) {
  const std::string pre = prefix("cloud");
  const PublisherParams p = params(pre);
  auto pub = Publisher::start(p);
  ASSERT_TRUE(pub) << pub.message();
  alg::TsdfMap map = twoSpheres();
  const Trajectory trajectory{{1, poseAt(0)}};
  auto expectedPoints = [&] {
    size_t n = 0;
    for (const auto& r : alg::changedRegions(map, 0, p.region_blocks)) {
      const alg::TriangleMesh mesh = alg::regionMesh(map, r, p.region_blocks, p.mesh);
      for (const auto& part : alg::splitMesh(mesh, static_cast<size_t>(p.max_triangles_per_chunk))) {
        n += part.vertices.size();
      }
    }
    return n;
  };
  (*pub)->flush(map, trajectory, RunCounters{});
  const size_t full = expectedPoints();
  ASSERT_GT(full, 1000u);
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  auto reader = Reader::create(*participant, topicType(Topic::kMapCloud), topicName(Topic::kMapCloud, pre),
                               topicQos(Topic::kMapCloud));
  ASSERT_TRUE(reader) << reader.message();
  PointCloudMessage cloud;
  size_t bad = 0;
  auto drain = [&] {
    (void)reader->take([&](const void* s, const dds_sample_info_t&) {
      auto c = fromWire(*static_cast<const sensor_msgs_msg_dds__PointCloud2_*>(s));
      if (c)
        cloud = std::move(*c);
      else
        ++bad;
    });
  };
  ASSERT_TRUE(waitFor(
      [&] {
        drain();
        return cloud.points.size() == full;
      },
      20))
      << cloud.points.size() << " of " << full;
  EXPECT_EQ(bad, 0u);
  EXPECT_EQ(cloud.frame_id, "map");
  ASSERT_EQ(cloud.colors.size(), cloud.points.size());
  // Every point lies on one of the two spheres (within a voxel).
  for (const auto& x : cloud.points) {
    const float d = std::min(std::abs((x - Eigen::Vector3f(0.05f, -0.07f, 0.11f)).norm() - 0.23f),
                             std::abs((x - Eigen::Vector3f(0.9f, 0.1f, 0.4f)).norm() - 0.12f));
    ASSERT_LT(d, 0.02f) << x.transpose();
  }
  // After a carve the next sample is the smaller map.
  carveAround(map, {0.9f, 0.1f, 0.4f});
  (*pub)->flush(map, trajectory, RunCounters{});
  const size_t carved = expectedPoints();
  ASSERT_LT(carved, full);
  ASSERT_TRUE(waitFor(
      [&] {
        drain();
        return cloud.points.size() == carved;
      },
      20))
      << cloud.points.size() << " of " << carved;
  EXPECT_EQ((*pub)->stats().clouds, 2u);
}

TEST(DdsMessages, APointCloudWhoseSizesDisagreeIsAnError) {
  PointCloudMessage m;
  m.frame_id = "map";
  m.points = {{1, 2, 3}, {4, 5, 6}};
  m.colors = {{{10, 20, 30}}, {{40, 50, 60}}};
  PointCloudWire wire(m);
  auto back = fromWire(wire.wire);
  ASSERT_TRUE(back) << back.message();
  EXPECT_EQ(back->points[1], Eigen::Vector3f(4, 5, 6));
  EXPECT_EQ(back->colors[1][2], 60);
  wire.wire.width = 3;  // claims a point the data does not hold
  auto bad = fromWire(wire.wire);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.message().find("data bytes"), std::string::npos) << bad.message();
}

// A publisher and, matched with it, a reader of the map as markers and
// one of its chunks, on the test's own topic names.
class DdsMapLoopback : public ::testing::Test {
 protected:
  void start(const std::string& name, const std::function<bool(const alg::BlockKey&, alg::VoxelBlock&)>& read = {}) {
    const std::string pre = prefix(name.c_str());
    PublisherParams p = params(pre);
    p.read_elsewhere = read;
    auto pub = Publisher::start(p);
    ASSERT_TRUE(pub) << pub.message();
    pub_ = std::move(*pub);
    auto participant = Participant::create(kDomain);
    ASSERT_TRUE(participant) << participant.message();
    participant_.emplace(std::move(*participant));
    auto reader =
        Reader::create(*participant_, topicType(Topic::kMap), topicName(Topic::kMap, pre), topicQos(Topic::kMap));
    auto chunks = Reader::create(*participant_, topicType(Topic::kMapChunks), topicName(Topic::kMapChunks, pre),
                                 topicQos(Topic::kMapChunks));
    ASSERT_TRUE(reader && chunks);
    reader_.emplace(std::move(*reader));
    chunks_.emplace(std::move(*chunks));
    ASSERT_TRUE(waitFor([&] { return pub_->matchedReaders(Topic::kMap) == 1; }, 20));
  }
  /// Takes what both readers have; true when each holds `triangles`.
  bool hold(size_t triangles) {
    drainMarkers(*reader_, markers_);
    drainMap(*chunks_, received_);
    return markers_.totals().first == triangles && received_.totals().first == triangles;
  }
  ::testing::AssertionResult reach(size_t triangles) {
    if (waitFor([&] { return hold(triangles); }, 20)) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << markers_.totals().first << " and " << received_.totals().first
                                         << " triangles, expected " << triangles;
  }
  std::unique_ptr<Publisher> pub_;
  std::optional<Participant> participant_;
  std::optional<Reader> reader_, chunks_;
  ReceivedMarkers markers_;
  ReceivedMap received_;
};

// A loop closure replaces the map with one fused anew from the keyframes;
// regions the new map does not hold must leave the readers' maps too.
TEST_F(DdsMapLoopback, RegionsAMapReplacementNoLongerHoldsAreDeleted) {
  ASSERT_NO_FATAL_FAILURE(start("replace"));
  const alg::TsdfMap before = twoSpheres();
  const Trajectory trajectory{{1, poseAt(0)}};
  pub_->flush(before, trajectory, RunCounters{});
  alg::TsdfMap after(tsdfParams());  // the first sphere only
  addSphere(after, {0.05f, -0.07f, 0.11f}, 0.23f);
  after.markAllChanged(before.revision());
  pub_->flush(after, trajectory, RunCounters{});
  EXPECT_TRUE(reach(alg::extractMesh(after, alg::MeshParams{}).triangles.size()));
}

TEST_F(DdsMapLoopback, ARegionWithBlocksOutOfMemoryKeepsItsLastMeshUntilTheyAreBack) {
  // Under a memory budget, blocks move out to disk while the map changes
  // beside them: a region re-meshed then would go out without their
  // surface, and readers would drop it.
  ASSERT_NO_FATAL_FAILURE(start("budget"));
  alg::TsdfMap map = twoSpheres();
  const Trajectory trajectory{{1, poseAt(0)}};
  pub_->flush(map, trajectory, RunCounters{});
  const size_t expected = alg::extractMesh(map, alg::MeshParams{}).triangles.size();
  ASSERT_TRUE(reach(expected));
  // Every other block out; every block left marked changed.
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  map.setBacking(store->get());
  std::vector<int32_t> out;
  for (size_t b = 0; b < map.blockCount(); b += 2) out.push_back(static_cast<int32_t>(b));
  ASSERT_EQ(map.removeBlocks(out), 0u);
  map.markAllChanged(map.revision());
  pub_->flush(map, trajectory, RunCounters{});
  const PublisherStats held = pub_->stats();
  EXPECT_GT(held.region_waits, 0u);
  // Nothing is lost meanwhile: the readers hold every triangle still.
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_TRUE(hold(expected)) << markers_.totals().first << " and " << received_.totals().first << " of " << expected;
  // Back in memory, the regions held back go out (the same surface).
  for (const Eigen::Vector3i& k : map.blocksElsewhere().keys()) map.findOrAllocate(k);
  pub_->flush(map, trajectory, RunCounters{});
  const PublisherStats sent = pub_->stats();
  EXPECT_GT(held.regions_waiting, 0u);
  EXPECT_EQ(sent.regions_waiting, 0u);
  EXPECT_EQ(sent.region_waits, held.region_waits);
  EXPECT_GT(sent.regions, held.regions);
  EXPECT_TRUE(reach(expected));
}

TEST_F(DdsMapLoopback, ARegionWithBlocksOutOfMemoryReadsThemFromTheBlockStore) {
  // As above, with the block store to read: the changed regions go out at
  // once, with the surface of the blocks on disk. A block that no longer
  // reads (taken back into memory since the update) holds its region back
  // until the next update.
  auto store = drv::BlockStore::create(::testing::TempDir());
  ASSERT_TRUE(store) << store.message();
  drv::BlockStore* s = store->get();
  std::atomic<int> refuse{0};  // the next reads that fail
  ASSERT_NO_FATAL_FAILURE(start("budget_read", [s, &refuse](const alg::BlockKey& k, alg::VoxelBlock& b) {
    if (refuse.load() > 0) {
      refuse.fetch_sub(1);
      return false;
    }
    return s->peek(k, b);
  }));
  alg::TsdfMap map = twoSpheres();
  const Trajectory trajectory{{1, poseAt(0)}};
  pub_->flush(map, trajectory, RunCounters{});
  const alg::TriangleMesh whole = alg::extractMesh(map, alg::MeshParams{});
  ASSERT_TRUE(reach(whole.triangles.size()));
  map.setBacking(s);
  std::vector<int32_t> out;
  for (size_t b = 0; b < map.blockCount(); b += 2) out.push_back(static_cast<int32_t>(b));
  ASSERT_EQ(map.removeBlocks(out), 0u);
  // The blocks left in memory change (a new surface among them), every
  // region is marked changed.
  addSphere(map, {0.05f, -0.07f, 0.11f}, 0.05f);
  map.markAllChanged(map.revision());
  refuse = 3;
  pub_->flush(map, trajectory, RunCounters{});
  const PublisherStats first = pub_->stats();
  EXPECT_EQ(first.region_waits, 0u);
  EXPECT_GT(first.blocks_read_elsewhere, out.size() / 2);
  EXPECT_GE(first.region_retries, 1u);
  EXPECT_LE(first.region_retries, 3u);
  EXPECT_EQ(first.regions_waiting, first.region_retries);
  pub_->flush(map, trajectory, RunCounters{});
  const PublisherStats second = pub_->stats();
  EXPECT_EQ(second.regions_waiting, 0u);
  EXPECT_EQ(second.region_retries, first.region_retries);
  // What the readers hold is the mesh of the map with every block back.
  alg::TsdfMap back = map;
  for (const Eigen::Vector3i& k : map.blocksElsewhere().keys()) {
    alg::VoxelBlock b;
    ASSERT_TRUE(s->peek(k, b));
    back.block(static_cast<size_t>(back.findOrAllocate(k))) = b;
  }
  const size_t expected = alg::extractMesh(back, alg::MeshParams{}).triangles.size();
  EXPECT_NE(expected, whole.triangles.size()) << "the map changed";
  EXPECT_TRUE(reach(expected));
}

// /tf as tf2_ros's listener subscribes (reliable, volatile, keep last 100):
// The transforms for `child` a /tf or /tf_static reader has now.
std::vector<TransformMessage> takeTransforms(Reader& reader, const std::string& child) {
  std::vector<TransformMessage> out;
  (void)reader.take([&](const void* s, const dds_sample_info_t&) {
    for (const auto& t : fromWire(*static_cast<const tf2_msgs_msg_dds__TFMessage_*>(s))) {
      if (t.child_frame_id == child) out.push_back(t);
    }
  });
  return out;
}

// frame_id -> child_frame_id per tracked frame, the camera's pose.
TEST(DdsLoopback, EveryTrackedFrameGoesOutOnTf) {
  const std::string pre = prefix("tf");
  PublisherParams p = params(pre);
  p.child_frame_id = pre + "_camera_optical_frame";  // /tf is shared by every test process
  p.stamp_offset_ns = 86'400'000'000'000;  // as a live camera's monotonic stamps are moved to the ROS epoch
  auto pub = Publisher::start(p);
  ASSERT_TRUE(pub) << pub.message();
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  EXPECT_EQ(topicName(Topic::kTf, pre), "rt/tf");
  EXPECT_STREQ(topicType(Topic::kTf)->m_typename, "tf2_msgs::msg::dds_::TFMessage_");
  auto reader = Reader::create(*participant, topicType(Topic::kTf), "rt/tf", {true, false, 100});
  ASSERT_TRUE(reader) << reader.message();
  ASSERT_TRUE(waitFor([&] { return (*pub)->matchedReaders(Topic::kTf) > 0 && reader->matchedWriters() > 0; }, 20));
  alg::TsdfMap map(tsdfParams());
  Trajectory trajectory;
  std::map<int64_t, Eigen::Isometry3d> sent;
  for (int k = 0; k < 10; ++k) {
    FrameResult r = frame(k);
    if (k == 3) r.tracked = false;
    else sent[r.stamp_ns + p.stamp_offset_ns] = r.T_world_cam;
    trajectory.push_back({r.stamp_ns, r.T_world_cam});
    (*pub)->onFrame(r, map, trajectory, RunCounters{});
  }
  std::map<int64_t, TransformMessage> received;
  ASSERT_TRUE(waitFor(
      [&] {
        for (const auto& t : takeTransforms(*reader, p.child_frame_id)) received[t.stamp_ns] = t;
        return received.size() >= sent.size();
      },
      20));
  ASSERT_EQ(received.size(), 9u);
  for (const auto& [stamp, t] : received) {
    ASSERT_TRUE(sent.count(stamp)) << stamp;
    EXPECT_EQ(t.frame_id, "map");
    EXPECT_LT((t.T_parent_child.matrix() - sent[stamp].matrix()).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_EQ((*pub)->stats().transforms, 9u);
}

// With a robot base (REP 105): /tf carries map -> base per tracked frame,
// /tf_static the camera's mount once, and a late joiner still gets it;
// the two composed are the camera's pose.
TEST(DdsLoopback, ABaseFrameGoesOnTfAndTheCameraMountOnTfStatic) {
  const std::string pre = prefix("tf_base");
  PublisherParams p = params(pre);
  p.base_frame_id = pre + "_base_link";
  p.child_frame_id = pre + "_camera_optical_frame";
  p.T_base_cam = alg::mountedOptical({0.2, 0.0, 0.3}, {0.0, 10.0, 0.0});  // 20 cm ahead, 30 cm up, tilted 10 deg down
  auto pub = Publisher::start(p);
  ASSERT_TRUE(pub) << pub.message();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // the static transform is out before anyone listens
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  EXPECT_EQ(topicName(Topic::kTfStatic, pre), "rt/tf_static");
  auto tf = Reader::create(*participant, topicType(Topic::kTf), "rt/tf", topicQos(Topic::kTf));
  auto tf_static =
      Reader::create(*participant, topicType(Topic::kTfStatic), "rt/tf_static", topicQos(Topic::kTfStatic));
  ASSERT_TRUE(tf && tf_static);
  std::vector<TransformMessage> fixed;
  ASSERT_TRUE(waitFor(
      [&] {
        fixed = takeTransforms(*tf_static, p.child_frame_id);
        return !fixed.empty();
      },
      20))
      << "a late joiner receives the static transform";
  ASSERT_EQ(fixed.size(), 1u);
  EXPECT_EQ(fixed[0].frame_id, p.base_frame_id);
  EXPECT_LT((fixed[0].T_parent_child.matrix() - p.T_base_cam.matrix()).cwiseAbs().maxCoeff(), 1e-12);
  // The optical z axis (forward) points along the base's x, tilted down.
  const Eigen::Vector3d forward = fixed[0].T_parent_child.linear().col(2);
  EXPECT_NEAR(forward.x(), std::cos(10 * M_PI / 180), 1e-12);
  EXPECT_NEAR(forward.z(), -std::sin(10 * M_PI / 180), 1e-12);

  ASSERT_TRUE(waitFor([&] { return (*pub)->matchedReaders(Topic::kTf) > 0 && tf->matchedWriters() > 0; }, 20));
  alg::TsdfMap map(tsdfParams());
  Trajectory trajectory;
  const FrameResult r = frame(4);
  trajectory.push_back({r.stamp_ns, r.T_world_cam});
  (*pub)->onFrame(r, map, trajectory, RunCounters{});
  std::vector<TransformMessage> moving;
  ASSERT_TRUE(waitFor(
      [&] {
        moving = takeTransforms(*tf, p.base_frame_id);
        return !moving.empty();
      },
      20));
  EXPECT_EQ(moving[0].frame_id, "map");
  const Eigen::Isometry3d T_map_cam = moving[0].T_parent_child * fixed[0].T_parent_child;
  EXPECT_LT((T_map_cam.matrix() - r.T_world_cam.matrix()).cwiseAbs().maxCoeff(), 1e-12);
}

// REP 105 on a robot with loop closure: map -> odom carries what closures
// corrected, odom -> base_link follows the odometry and never jumps.
TEST(DdsLoopback, WithAnOdomFrameAClosureMovesMapToOdomAndOdomToBaseStaysContinuous) {
  const std::string pre = prefix("tf_odom");
  PublisherParams p = params(pre);
  p.base_frame_id = pre + "_base_link";
  p.odom_frame_id = pre + "_odom";
  p.T_base_cam = alg::mountedOptical({0.1, 0.0, 0.2}, {0.0, 0.0, 0.0});
  auto pub = Publisher::start(p);
  ASSERT_TRUE(pub) << pub.message();
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  auto tf = Reader::create(*participant, topicType(Topic::kTf), "rt/tf", topicQos(Topic::kTf));
  ASSERT_TRUE(tf) << tf.message();
  auto odom =
      Reader::create(*participant, topicType(Topic::kOdom), topicName(Topic::kOdom, pre), topicQos(Topic::kOdom));
  ASSERT_TRUE(odom) << odom.message();
  ASSERT_TRUE(waitFor(
      [&] { return (*pub)->matchedReaders(Topic::kTf) > 0 && tf->matchedWriters() > 0 && odom->matchedWriters() > 0; },
      20));
  // Two frames 1 cm apart in odometry; a closure between them moved the
  // world by 5 cm and 2 degrees.
  const Eigen::Isometry3d correction =
      alg::expSE3((Eigen::Matrix<double, 6, 1>() << 0.05, -0.01, 0.0, 0.0, 0.0, 0.035).finished());
  FrameResult a = frame(1), b = frame(2);
  b.T_world_cam = correction * a.T_world_cam * Eigen::Translation3d(0.01, 0, 0);
  b.T_world_odom = correction;
  alg::TsdfMap map(tsdfParams());
  Trajectory trajectory;
  for (const FrameResult* r : {&a, &b}) {
    trajectory.push_back({r->stamp_ns, r->T_world_cam});
    (*pub)->onFrame(*r, map, trajectory, RunCounters{});
  }
  std::vector<TransformMessage> to_odom, to_base;
  ASSERT_TRUE(waitFor(
      [&] {
        (void)tf->take([&](const void* s, const dds_sample_info_t&) {
          for (const auto& t : fromWire(*static_cast<const tf2_msgs_msg_dds__TFMessage_*>(s))) {
            if (t.child_frame_id == p.odom_frame_id) to_odom.push_back(t);
            if (t.child_frame_id == p.base_frame_id) to_base.push_back(t);
          }
        });
        return to_odom.size() == 2 && to_base.size() == 2;
      },
      20))
      << to_odom.size() << " map->odom, " << to_base.size() << " odom->base";
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(to_odom[i].frame_id, "map");
    EXPECT_EQ(to_base[i].frame_id, p.odom_frame_id);
    const FrameResult& r = i == 0 ? a : b;
    const Eigen::Isometry3d T_map_cam = to_odom[i].T_parent_child * to_base[i].T_parent_child * p.T_base_cam;
    EXPECT_LT((T_map_cam.matrix() - r.T_world_cam.matrix()).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_LT((to_odom[0].T_parent_child.matrix() - Eigen::Matrix4d::Identity()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((to_odom[1].T_parent_child.matrix() - correction.matrix()).cwiseAbs().maxCoeff(), 1e-12);
  // In odom the base moved by the odometry's 1 cm, not by the correction.
  const Eigen::Isometry3d step = to_base[0].T_parent_child.inverse() * to_base[1].T_parent_child;
  EXPECT_NEAR(step.translation().norm(), 0.01, 1e-9);
  EXPECT_NEAR(Eigen::AngleAxisd(step.linear()).angle(), 0.0, 1e-9);
  // nav_msgs/Odometry: the odom -> base link, with the velocity in the base
  // frame (1 cm in 33.3 ms: 0.3 m/s along the base's own motion).
  std::vector<OdometryMessage> odoms;
  ASSERT_TRUE(waitFor(
      [&] {
        (void)odom->take([&](const void* s, const dds_sample_info_t&) {
          odoms.push_back(fromWire(*static_cast<const nav_msgs_msg_dds__Odometry_*>(s)));
        });
        return odoms.size() == 2;
      },
      20));
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(odoms[i].frame_id, p.odom_frame_id);
    EXPECT_EQ(odoms[i].child_frame_id, p.base_frame_id);
    EXPECT_LT((odoms[i].T_parent_child.matrix() - to_base[i].T_parent_child.matrix()).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_NEAR(odoms[1].linear.norm(), 0.01 / 0.033333333, 1e-6);
  EXPECT_LT((odoms[1].linear / odoms[1].linear.norm() - step.translation() / step.translation().norm()).norm(), 1e-9);
  EXPECT_NEAR(odoms[1].angular.norm(), 0.0, 1e-9);
}

// ROS 2's readers accept XCDR1 only; Cyclone would pick XCDR2 by itself
// for types that are not final.
TEST(DdsLoopback, EveryWriterOffersXcdr1Only) {
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  for (Topic t : kAllTopics) {
    auto w = Writer::create(*participant, topicType(t), topicName(t, prefix("xcdr")), topicQos(t));
    ASSERT_TRUE(w) << w.message();
    dds_qos_t* qos = dds_create_qos();
    ASSERT_EQ(dds_get_qos(w->get(), qos), DDS_RETCODE_OK);
    uint32_t n = 0;
    dds_data_representation_id_t* ids = nullptr;
    ASSERT_TRUE(dds_qget_data_representation(qos, &n, &ids));
    ASSERT_EQ(n, 1u) << w->topic();
    EXPECT_EQ(ids[0], DDS_DATA_REPRESENTATION_XCDR1) << w->topic();
    dds_free(ids);
    dds_delete_qos(qos);
  }
}

TEST(RosTypeHash, Sha256MatchesTheStandardsTestVectors) {
  EXPECT_EQ(sha256Hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(sha256Hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  EXPECT_EQ(sha256Hex(std::string(1000000, 'a')), "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

TEST(RosTypeHash, AreThoseRos2JazzyComputesForTheSameTypes) {
  // The values ROS 2 Jazzy's rosidl generates from geometry_msgs and
  // nav_msgs; hxmap computes them from its own IDL.
  const auto& hashes = wireTypeHashes();
  EXPECT_EQ(hashes.at("geometry_msgs::msg::dds_::PoseStamped_"),
            "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8");
  EXPECT_EQ(hashes.at("nav_msgs::msg::dds_::Path_"),
            "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b");
  for (Topic t : kAllTopics) EXPECT_EQ(hashes.count(topicType(t)->m_typename), 1u) << topicType(t)->m_typename;
  // A type that does not follow the convention is an error with its line.
  auto bad = rosTypeHashes("module a {\n struct B { int32 x; };\n};\n", "t.idl");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.message().find("t.idl:2: struct a::B is not named pkg::msg::dds_::Name_"), std::string::npos)
      << bad.message();
}

TEST(DdsLoopback, EndpointsAndTheParticipantSayWhatRos2NodesSay) {
  // What a ROS 2 Jazzy node reads from discovery: `enclave=/;` on the
  // participant, `typehash=RIHS01_...;` on every endpoint.
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  const std::string topic = topicName(Topic::kPose, prefix("typehash"));
  auto w = Writer::create(*participant, topicType(Topic::kPose), topic, topicQos(Topic::kPose));
  ASSERT_TRUE(w) << w.message();
  auto userData = [](const dds_qos_t* qos) {
    void* value = nullptr;
    size_t size = 0;
    std::string s;
    if (qos && dds_qget_userdata(qos, &value, &size) && value) s.assign(static_cast<const char*>(value), size);
    dds_free(value);
    return s;
  };
  const dds_entity_t pubs = dds_create_reader(participant->get(), DDS_BUILTIN_TOPIC_DCPSPUBLICATION, nullptr, nullptr);
  ASSERT_GT(pubs, 0);
  std::string seen;
  EXPECT_TRUE(waitFor(
      [&] {
        void* samples[8] = {};
        dds_sample_info_t infos[8];
        const int n = dds_take(pubs, samples, infos, 8, 8);
        for (int k = 0; k < n; ++k) {
          const auto* e = static_cast<const dds_builtintopic_endpoint_t*>(samples[k]);
          if (infos[k].valid_data && topic == e->topic_name) seen = userData(e->qos);
        }
        if (n > 0) dds_return_loan(pubs, samples, n);
        return !seen.empty();
      },
      10.0));
  EXPECT_EQ(seen, "typehash=RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8;");
  dds_qos_t* qos = dds_create_qos();
  ASSERT_EQ(dds_get_qos(participant->get(), qos), DDS_RETCODE_OK);
  EXPECT_EQ(userData(qos), "enclave=/;");
  dds_delete_qos(qos);
  dds_delete(pubs);
}

TEST(DdsLoopback, ThePathCarriesTheNewestPosesOnly) {
  const std::string pre = prefix("path");
  PublisherParams p = params(pre);
  p.path_max_poses = 5;
  auto pub = Publisher::start(p);
  ASSERT_TRUE(pub) << pub.message();
  Trajectory trajectory;
  for (int k = 0; k < 12; ++k) trajectory.push_back({1000 + k, poseAt(k)});
  (*pub)->flush(alg::TsdfMap(tsdfParams()), trajectory, RunCounters{});
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant) << participant.message();
  auto reader = Reader::create(*participant, topicType(Topic::kTrajectory), topicName(Topic::kTrajectory, pre),
                               topicQos(Topic::kTrajectory));
  ASSERT_TRUE(reader) << reader.message();
  PathMessage path;
  ASSERT_TRUE(waitFor([&] {
    (void)reader->take([&](const void* s, const dds_sample_info_t&) {
      path = fromWire(*static_cast<const nav_msgs_msg_dds__Path_*>(s));
    });
    return !path.poses.empty();
  }, 20));
  ASSERT_EQ(path.poses.size(), 5u);
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(path.poses[i].stamp_ns, 1007 + static_cast<int64_t>(i));
    EXPECT_LT((path.poses[i].T_world_cam.matrix() - poseAt(static_cast<int>(7 + i)).matrix()).cwiseAbs().maxCoeff(),
              1e-12);
  }
}

TEST(DdsLoopback, HealthCarriesTheRunnersCounters) {
  const std::string pre = prefix("health");
  auto pub = Publisher::start(params(pre));
  ASSERT_TRUE(pub) << pub.message();
  alg::TsdfMap map(tsdfParams());
  Trajectory trajectory;
  for (int k = 0; k < 6; ++k) {
    FrameResult r = frame(k);
    r.tracked = k != 2;
    r.keyframe = k % 3 == 0;
    r.stage_ms = {1, 2, 3, 4, 0};
    trajectory.push_back({r.stamp_ns, r.T_world_cam});
    (*pub)->onFrame(r, map, trajectory, RunCounters{3, 2, 5, 1, 12.5});
  }
  (*pub)->flush(map, trajectory, RunCounters{4, 2, 6, 1, 0});
  auto participant = Participant::create(kDomain);
  ASSERT_TRUE(participant);
  auto reader = Reader::create(*participant, topicType(Topic::kHealth), topicName(Topic::kHealth, pre), topicQos(Topic::kHealth));
  ASSERT_TRUE(reader) << reader.message();
  HealthMessage h;
  bool got = false;
  ASSERT_TRUE(waitFor([&] {
    (void)reader->take([&](const void* s, const dds_sample_info_t&) {
      h = fromWire(*static_cast<const hxmap_msgs_msg_dds__Health_*>(s));
      got = true;
    });
    return got;
  }, 20));
  EXPECT_EQ(h.frames, 6u);
  EXPECT_EQ(h.frames_lost, 1u);
  EXPECT_EQ(h.keyframes, 2u);
  EXPECT_EQ(h.frames_dropped, 4u);
  EXPECT_EQ(h.deadline_misses, 2u);
  EXPECT_EQ(h.refine_jobs_done, 6u);
  EXPECT_EQ(h.refine_jobs_shed, 1u);
  EXPECT_FLOAT_EQ(h.frontend_ms_p50, 10.0f);
  EXPECT_FLOAT_EQ(h.latency_ms_p50, 12.5f);
}

// `hxmap echo` in its own process: poses (best effort, published until the
// echo has what it asked for) and a late-joining map.
// The domain comes from ROS_DOMAIN_ID when neither --domain nor
// dds.domain_id sets it (the echo below finds the publisher that way); a
// value ROS 2 would not accept is a usage error naming the variable.
TEST(DdsErrors, ABadRosDomainIdIsAUsageErrorNamingIt) {
  const std::string cmd = fmt::format("ROS_DOMAIN_ID=twelve '{}' echo pose --count 1 --timeout 1 2>&1", HXMAP_BIN);
  FILE* pipe = popen(cmd.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string out;
  char buf[512];
  while (fgets(buf, sizeof buf, pipe) != nullptr) out += buf;
  const int status = pclose(pipe);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 2) << out;
  EXPECT_NE(out.find("ROS_DOMAIN_ID: 'twelve' is not a DDS domain id"), std::string::npos) << out;
}

TEST(DdsLoopback, EchoInASeparateProcessPrintsThePublishedValues) {
  const std::string pre = prefix("echo");
  auto pub = Publisher::start(params(pre));
  ASSERT_TRUE(pub) << pub.message();
  alg::TsdfMap map(tsdfParams());
  addSphere(map, {0.0f, 0.0f, 1.0f}, 0.2f);
  Trajectory trajectory;

  const std::string cmd =
      fmt::format("ROS_DOMAIN_ID={} '{}' -q echo pose --count 3 --timeout 30 --prefix {}", kDomain, HXMAP_BIN, pre);
  FILE* pipe = popen(cmd.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string out;
  std::atomic<bool> done{false};
  std::thread collect([&] {
    char buf[512];
    while (fgets(buf, sizeof buf, pipe) != nullptr) out += buf;
    done = true;
  });
  std::map<int64_t, Eigen::Isometry3d> sent;
  for (int k = 0; k < 1500 && !done; ++k) {  // at most 30 s
    const FrameResult r = frame(k);
    sent[r.stamp_ns] = r.T_world_cam;
    trajectory.push_back({r.stamp_ns, r.T_world_cam});
    (*pub)->onFrame(r, map, trajectory, RunCounters{});
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  collect.join();
  EXPECT_EQ(pclose(pipe), 0) << out;
  std::istringstream lines(out);
  std::string line;
  int n = 0;
  while (std::getline(lines, line)) {
    std::istringstream in(line);
    std::string word, stamp, frame_id, t_word, q_word;
    Eigen::Vector3d t;
    Eigen::Vector4d q;
    in >> word >> stamp >> frame_id >> t_word >> t.x() >> t.y() >> t.z() >> q_word >> q[0] >> q[1] >> q[2] >> q[3];
    ASSERT_EQ(word, "pose") << line;
    ASSERT_EQ(frame_id, "map");
    const size_t dot = stamp.find('.');
    const int64_t ns = std::stoll(stamp.substr(0, dot)) * 1'000'000'000 + std::stoll(stamp.substr(dot + 1));
    ASSERT_TRUE(sent.count(ns)) << line;
    EXPECT_LT((t - sent[ns].translation()).cwiseAbs().maxCoeff(), 1.5e-6) << line;
    const Eigen::Quaterniond qs(sent[ns].linear());
    EXPECT_NEAR(std::abs(q[0] * qs.x() + q[1] * qs.y() + q[2] * qs.z() + q[3] * qs.w()), 1.0, 1e-5) << line;
    ++n;
  }
  EXPECT_EQ(n, 3);

  // The map, written before the echo starts.
  (*pub)->flush(map, trajectory, RunCounters{});
  const PublisherStats s = (*pub)->stats();
  const std::string map_cmd = fmt::format("'{}' -q echo map_chunks --count {} --timeout 30 --domain {} --prefix {}",
                                          HXMAP_BIN, s.chunks, kDomain, pre);
  FILE* map_pipe = popen(map_cmd.c_str(), "r");
  ASSERT_NE(map_pipe, nullptr);
  std::string map_out;
  char buf[512];
  while (fgets(buf, sizeof buf, map_pipe) != nullptr) map_out += buf;
  EXPECT_EQ(pclose(map_pipe), 0) << map_out;
  size_t triangles = 0, chunks = 0;
  std::istringstream map_lines(map_out);
  while (std::getline(map_lines, line)) {
    const size_t at = line.find(" triangles ");
    ASSERT_NE(at, std::string::npos) << line;
    triangles += std::stoul(line.substr(at + 11));
    ++chunks;
  }
  EXPECT_EQ(chunks, s.chunks);
  EXPECT_EQ(triangles, alg::extractMesh(map, alg::MeshParams{}).triangles.size());
}

TEST(DdsErrors, BadDomainIsAClearError) {
  PublisherParams p = params(prefix("bad"));
  p.domain_id = 4000;
  auto pub = Publisher::start(p);
  ASSERT_FALSE(pub);
  EXPECT_NE(pub.message().find("domain 4000"), std::string::npos) << pub.message();
  p.domain_id = kDomain;
  p.region_blocks = 0;
  auto pub2 = Publisher::start(p);
  ASSERT_FALSE(pub2);
  EXPECT_NE(pub2.message().find("region_blocks"), std::string::npos) << pub2.message();
}

}  // namespace
}  // namespace hxmap::rt::dds
