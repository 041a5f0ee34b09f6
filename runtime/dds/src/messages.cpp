#include "hxmap/dds/messages.hpp"

#include <cstring>

#include <fmt/format.h>

namespace hxmap::rt::dds {

namespace {

builtin_interfaces_msg_dds__Time_ toTime(int64_t ns) {
  int64_t sec = ns / 1000000000;
  int64_t rem = ns % 1000000000;
  if (rem < 0) {
    rem += 1000000000;
    --sec;
  }
  return {static_cast<int32_t>(sec), static_cast<uint32_t>(rem)};
}

int64_t fromTime(const builtin_interfaces_msg_dds__Time_& t) {
  return static_cast<int64_t>(t.sec) * 1000000000 + static_cast<int64_t>(t.nanosec);
}

// Sequences point at the message's storage; _release false: Cyclone never frees them.
template <class Seq, class T>
Seq view(const std::vector<T>& v) {
  Seq s{};
  s._maximum = s._length = static_cast<uint32_t>(v.size());
  s._buffer = const_cast<T*>(v.data());
  s._release = false;
  return s;
}

// Header strings point into `frame_id`, which must outlive the wire struct.
std_msgs_msg_dds__Header_ toHeader(int64_t stamp_ns, const std::string& frame_id) {
  return {toTime(stamp_ns), const_cast<char*>(frame_id.c_str())};
}

// A rigid transform as ROS 2's Pose (position, orientation).
geometry_msgs_msg_dds__Pose_ toPose(const Eigen::Isometry3d& T) {
  const Eigen::Vector3d t = T.translation();
  const Eigen::Quaterniond q(T.linear());
  return {{t.x(), t.y(), t.z()}, {q.x(), q.y(), q.z(), q.w()}};
}

void fillPose(geometry_msgs_msg_dds__PoseStamped_& w, int64_t stamp_ns, const std::string& frame_id,
              const Eigen::Isometry3d& T_world_cam) {
  w.header = toHeader(stamp_ns, frame_id);
  w.pose = toPose(T_world_cam);
}

// ROS 2's Pose as a rigid transform (a zero quaternion reads as identity).
Eigen::Isometry3d fromPose(const geometry_msgs_msg_dds__Point_& p, const geometry_msgs_msg_dds__Quaternion_& o) {
  Eigen::Quaterniond q(o.w, o.x, o.y, o.z);
  if (q.norm() > 0) q.normalize();
  else
    q.setIdentity();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q.toRotationMatrix();
  T.translation() = Eigen::Vector3d(p.x, p.y, p.z);
  return T;
}

StampedPose readPose(const geometry_msgs_msg_dds__PoseStamped_& w) {
  return {fromTime(w.header.stamp), fromPose(w.pose.position, w.pose.orientation)};
}

std::string str(const char* s) { return s != nullptr ? std::string(s) : std::string(); }

std::string stampText(int64_t ns) { return fmt::format("{}.{:09d}", ns / 1000000000, ns % 1000000000); }

}  // namespace

std::string topicName(Topic topic, const std::string& prefix) {
  if (topic == Topic::kTf) return "rt/tf";
  if (topic == Topic::kTfStatic) return "rt/tf_static";
  return fmt::format("rt/{}/{}", prefix, topicShortName(topic));
}

const char* topicShortName(Topic topic) {
  switch (topic) {
    case Topic::kPose: return "pose";
    case Topic::kOdom:
      return "odom";
    case Topic::kTrajectory: return "trajectory";
    case Topic::kMap: return "map";
    case Topic::kMapChunks:
      return "map_chunks";
    case Topic::kMapCloud:
      return "map_cloud";
    case Topic::kHealth: return "health";
    case Topic::kTf: return "tf";
    case Topic::kTfStatic:
      return "tf_static";
  }
  return "?";
}

Expected<Topic> topicFromString(const std::string& name) {
  for (Topic t : kAllTopics) {
    if (name == topicShortName(t)) return t;
  }
  return Error{fmt::format(
      "unknown topic '{}' (known: pose, odom, trajectory, map, map_chunks, map_cloud, health, tf, tf_static)", name)};
}

TopicQos topicQos(Topic topic) {
  switch (topic) {
    case Topic::kPose: return {true, false, 10};  // reliable: ROS 2's default readers ask for it (REP 2003)
    case Topic::kOdom:
      return {true, false, 10};
    case Topic::kTrajectory: return {true, true, 1};
    // Each sample is an increment: none may be replaced before a reader
    // has it; a slow reader makes hx-publish wait, never the frontend.
    case Topic::kMap:
      return {true, true, 1, true, 2.0};
    case Topic::kMapChunks:
      return {true, true, 1};
    case Topic::kMapCloud:
      return {true, true, 1};  // a state: the newest sample is the whole map
    case Topic::kHealth: return {true, true, 1};
    case Topic::kTf: return {true, false, 100};  // as tf2_ros's TransformBroadcaster
    case Topic::kTfStatic:
      return {true, true, 1};  // as tf2_ros's StaticTransformBroadcaster
  }
  return {};
}

const dds_topic_descriptor_t* topicType(Topic topic) {
  switch (topic) {
    case Topic::kPose: return &geometry_msgs_msg_dds__PoseStamped__desc;
    case Topic::kOdom:
      return &nav_msgs_msg_dds__Odometry__desc;
    case Topic::kTrajectory: return &nav_msgs_msg_dds__Path__desc;
    case Topic::kMap:
      return &visualization_msgs_msg_dds__MarkerArray__desc;
    case Topic::kMapChunks:
      return &hxmap_msgs_msg_dds__MapChunk__desc;
    case Topic::kMapCloud:
      return &sensor_msgs_msg_dds__PointCloud2__desc;
    case Topic::kHealth: return &hxmap_msgs_msg_dds__Health__desc;
    case Topic::kTf:
    case Topic::kTfStatic:
      return &tf2_msgs_msg_dds__TFMessage__desc;
  }
  return nullptr;
}

PoseWire::PoseWire(const PoseMessage& m) { fillPose(wire, m.stamp_ns, m.frame_id, m.T_world_cam); }

MarkerArrayWire::MarkerArrayWire(const std::vector<MarkerMessage>& in)
    : markers(in.size()), points(in.size()), colors(in.size()) {
  for (size_t i = 0; i < in.size(); ++i) {
    const MarkerMessage& m = in[i];
    visualization_msgs_msg_dds__Marker_& w = markers[i];
    w.header = toHeader(m.stamp_ns, m.frame_id);
    w.ns = const_cast<char*>(m.ns.c_str());
    w.id = m.id;
    w.type = m.type;
    w.action = m.action;
    w.pose.orientation.w = 1.0;
    w.scale = {1.0, 1.0, 1.0};
    w.color = {1.0f, 1.0f, 1.0f, 1.0f};
    points[i].reserve(m.points.size());
    for (const auto& p : m.points) points[i].push_back({p.x(), p.y(), p.z()});
    colors[i].reserve(m.colors.size());
    for (const auto& c : m.colors) colors[i].push_back({c[0], c[1], c[2], c[3]});
    w.points = view<dds_sequence_geometry_msgs_msg_dds__Point_>(points[i]);
    w.colors = view<dds_sequence_std_msgs_msg_dds__ColorRGBA_>(colors[i]);
    // Strings must not be null on the wire; the texture and mesh file stay empty.
    static char empty[] = "";
    w.texture_resource = w.text = w.mesh_resource = empty;
    w.texture.header.frame_id = w.texture.format = w.mesh_file.filename = empty;
  }
  wire.markers = view<dds_sequence_visualization_msgs_msg_dds__Marker_>(markers);
}

namespace {
constexpr uint8_t kFloat32 = 7;  // sensor_msgs/PointField::FLOAT32
char* fieldName(int i) {
  static char names[4][4] = {"x", "y", "z", "rgb"};
  return names[i];
}
}  // namespace

PointCloudWire::PointCloudWire(const PointCloudMessage& m) : fields(4), data(m.points.size() * 16) {
  for (int i = 0; i < 4; ++i)
    fields[static_cast<size_t>(i)] = {fieldName(i), static_cast<uint32_t>(4 * i), kFloat32, 1};
  for (size_t i = 0; i < m.points.size(); ++i) {
    uint8_t* p = data.data() + 16 * i;
    std::memcpy(p, m.points[i].data(), 12);
    const std::array<uint8_t, 3> c =
        m.colors.size() == m.points.size() ? m.colors[i] : std::array<uint8_t, 3>{255, 255, 255};
    const uint32_t rgb = static_cast<uint32_t>(c[0]) << 16 | static_cast<uint32_t>(c[1]) << 8 | c[2];
    std::memcpy(p + 12, &rgb, 4);  // little-endian, as is_bigendian says
  }
  wire.header = toHeader(m.stamp_ns, m.frame_id);
  wire.height = 1;
  wire.width = static_cast<uint32_t>(m.points.size());
  wire.fields = view<dds_sequence_sensor_msgs_msg_dds__PointField_>(fields);
  wire.is_bigendian = false;
  wire.point_step = 16;
  wire.row_step = 16 * wire.width;
  wire.data = view<dds_sequence_uint8>(data);
  wire.is_dense = true;
}

TfWire::TfWire(const std::vector<TransformMessage>& in) : transforms(in.size()) {
  for (size_t i = 0; i < in.size(); ++i) {
    const TransformMessage& m = in[i];
    geometry_msgs_msg_dds__TransformStamped_& w = transforms[i];
    w.header = toHeader(m.stamp_ns, m.frame_id);
    w.child_frame_id = const_cast<char*>(m.child_frame_id.c_str());
    const geometry_msgs_msg_dds__Pose_ pose = toPose(m.T_parent_child);
    w.transform.translation = {pose.position.x, pose.position.y, pose.position.z};
    w.transform.rotation = pose.orientation;
  }
  wire.transforms = view<dds_sequence_geometry_msgs_msg_dds__TransformStamped_>(transforms);
}

OdometryWire::OdometryWire(const OdometryMessage& m) {
  wire.header = toHeader(m.stamp_ns, m.frame_id);
  wire.child_frame_id = const_cast<char*>(m.child_frame_id.c_str());
  wire.pose.pose = toPose(m.T_parent_child);
  wire.twist.twist.linear = {m.linear.x(), m.linear.y(), m.linear.z()};
  wire.twist.twist.angular = {m.angular.x(), m.angular.y(), m.angular.z()};
}

PathWire::PathWire(const PathMessage& m) : poses(m.poses.size()) {
  for (size_t i = 0; i < m.poses.size(); ++i) fillPose(poses[i], m.poses[i].stamp_ns, m.frame_id, m.poses[i].T_world_cam);
  wire.header = toHeader(m.stamp_ns, m.frame_id);
  wire.poses = view<dds_sequence_geometry_msgs_msg_dds__PoseStamped_>(poses);
}

MapChunkWire::MapChunkWire(const MapChunkMessage& m) {
  wire.header = toHeader(m.stamp_ns, m.frame_id);
  wire.region_x = m.region.x();
  wire.region_y = m.region.y();
  wire.region_z = m.region.z();
  wire.part = m.part;
  wire.parts = m.parts;
  wire.revision = m.revision;
  wire.region_size_m = m.region_size_m;
  wire.vertices = view<dds_sequence_float>(m.vertices);
  wire.colors = view<dds_sequence_uint8>(m.colors);
  wire.triangles = view<dds_sequence_uint32>(m.triangles);
}

HealthWire::HealthWire(const HealthMessage& m) {
  wire.header = toHeader(m.stamp_ns, m.frame_id);
  wire.frames = m.frames;
  wire.frames_dropped = m.frames_dropped;
  wire.frames_lost = m.frames_lost;
  wire.deadline_misses = m.deadline_misses;
  wire.keyframes = m.keyframes;
  wire.refine_jobs_done = m.refine_jobs_done;
  wire.refine_jobs_shed = m.refine_jobs_shed;
  wire.messages_dropped = m.messages_dropped;
  wire.fps = m.fps;
  wire.latency_ms_p50 = m.latency_ms_p50;
  wire.latency_ms_max = m.latency_ms_max;
  wire.frontend_ms_p50 = m.frontend_ms_p50;
}

PoseMessage fromWire(const geometry_msgs_msg_dds__PoseStamped_& w) {
  const StampedPose p = readPose(w);
  return {p.stamp_ns, str(w.header.frame_id), p.T_world_cam};
}

PathMessage fromWire(const nav_msgs_msg_dds__Path_& w) {
  PathMessage m;
  m.stamp_ns = fromTime(w.header.stamp);
  m.frame_id = str(w.header.frame_id);
  m.poses.reserve(w.poses._length);
  for (uint32_t i = 0; i < w.poses._length; ++i) m.poses.push_back(readPose(w.poses._buffer[i]));
  return m;
}

OdometryMessage fromWire(const nav_msgs_msg_dds__Odometry_& w) {
  OdometryMessage m;
  m.stamp_ns = fromTime(w.header.stamp);
  m.frame_id = str(w.header.frame_id);
  m.child_frame_id = str(w.child_frame_id);
  m.T_parent_child = fromPose(w.pose.pose.position, w.pose.pose.orientation);
  m.linear = {w.twist.twist.linear.x, w.twist.twist.linear.y, w.twist.twist.linear.z};
  m.angular = {w.twist.twist.angular.x, w.twist.twist.angular.y, w.twist.twist.angular.z};
  return m;
}

Expected<MapChunkMessage> fromWire(const hxmap_msgs_msg_dds__MapChunk_& w) {
  MapChunkMessage m;
  m.stamp_ns = fromTime(w.header.stamp);
  m.frame_id = str(w.header.frame_id);
  m.region = {w.region_x, w.region_y, w.region_z};
  m.part = w.part;
  m.parts = w.parts;
  m.revision = w.revision;
  m.region_size_m = w.region_size_m;
  const std::string where = fmt::format("map chunk ({}, {}, {}) part {}", w.region_x, w.region_y, w.region_z, w.part);
  if (w.vertices._length % 3 != 0) return Error{fmt::format("{}: {} vertex floats, not 3 per vertex", where, w.vertices._length)};
  if (w.triangles._length % 3 != 0) return Error{fmt::format("{}: {} indices, not 3 per triangle", where, w.triangles._length)};
  if (w.colors._length != 0 && w.colors._length != w.vertices._length) {
    return Error{fmt::format("{}: {} color bytes for {} vertices", where, w.colors._length, w.vertices._length / 3)};
  }
  const uint32_t nv = w.vertices._length / 3;
  for (uint32_t i = 0; i < w.triangles._length; ++i) {
    if (w.triangles._buffer[i] >= nv) return Error{fmt::format("{}: index {} out of range ({} vertices)", where, w.triangles._buffer[i], nv)};
  }
  m.vertices.assign(w.vertices._buffer, w.vertices._buffer + w.vertices._length);
  m.colors.assign(w.colors._buffer, w.colors._buffer + w.colors._length);
  m.triangles.assign(w.triangles._buffer, w.triangles._buffer + w.triangles._length);
  return m;
}

Expected<std::vector<MarkerMessage>> fromWire(const visualization_msgs_msg_dds__MarkerArray_& w) {
  std::vector<MarkerMessage> out;
  out.reserve(w.markers._length);
  for (uint32_t i = 0; i < w.markers._length; ++i) {
    const visualization_msgs_msg_dds__Marker_& k = w.markers._buffer[i];
    MarkerMessage m;
    m.stamp_ns = fromTime(k.header.stamp);
    m.frame_id = str(k.header.frame_id);
    m.ns = str(k.ns);
    m.id = k.id;
    m.type = k.type;
    m.action = k.action;
    const std::string where = fmt::format("marker {} {}", m.ns, m.id);
    if (k.colors._length != 0 && k.colors._length != k.points._length) {
      return Error{fmt::format("{}: {} colors for {} points", where, k.colors._length, k.points._length)};
    }
    if (k.type == MarkerMessage::kTriangleList && k.points._length % 3 != 0) {
      return Error{fmt::format("{}: a triangle list of {} points, not 3 per triangle", where, k.points._length)};
    }
    m.points.reserve(k.points._length);
    for (uint32_t j = 0; j < k.points._length; ++j) {
      const auto& p = k.points._buffer[j];
      m.points.emplace_back(p.x, p.y, p.z);
    }
    m.colors.reserve(k.colors._length);
    for (uint32_t j = 0; j < k.colors._length; ++j) {
      const auto& c = k.colors._buffer[j];
      m.colors.emplace_back(c.r, c.g, c.b, c.a);
    }
    out.push_back(std::move(m));
  }
  return out;
}

Expected<PointCloudMessage> fromWire(const sensor_msgs_msg_dds__PointCloud2_& w) {
  PointCloudMessage m;
  m.stamp_ns = fromTime(w.header.stamp);
  m.frame_id = str(w.header.frame_id);
  int offset[4] = {-1, -1, -1, -1};  // x, y, z, rgb
  for (uint32_t i = 0; i < w.fields._length; ++i) {
    const auto& f = w.fields._buffer[i];
    const std::string name = str(f.name);
    for (int k = 0; k < 4; ++k) {
      if (name == fieldName(k) && f.datatype == kFloat32 && f.count == 1) offset[k] = static_cast<int>(f.offset);
    }
  }
  if (offset[0] < 0 || offset[1] < 0 || offset[2] < 0) return Error{"point cloud without float32 x, y and z fields"};
  if (w.is_bigendian) return Error{"big-endian point cloud"};
  const uint64_t n = static_cast<uint64_t>(w.width) * w.height;
  for (int k = 0; k < 4; ++k) {
    if (offset[k] >= 0 && static_cast<uint64_t>(offset[k]) + 4 > w.point_step) {
      return Error{
          fmt::format("point cloud field {} at {} beyond the point step {}", fieldName(k), offset[k], w.point_step)};
    }
  }
  if (w.row_step != static_cast<uint64_t>(w.width) * w.point_step || w.data._length != n * w.point_step) {
    return Error{fmt::format("point cloud of {}x{} points, step {}, row step {}: {} data bytes", w.width, w.height,
                             w.point_step, w.row_step, w.data._length)};
  }
  m.points.resize(n);
  if (offset[3] >= 0) m.colors.resize(n);
  for (uint64_t i = 0; i < n; ++i) {
    const uint8_t* p = w.data._buffer + i * w.point_step;
    for (int k = 0; k < 3; ++k) std::memcpy(&m.points[i][k], p + offset[k], 4);
    if (offset[3] >= 0) {
      uint32_t rgb = 0;
      std::memcpy(&rgb, p + offset[3], 4);
      m.colors[i] = {static_cast<uint8_t>(rgb >> 16), static_cast<uint8_t>(rgb >> 8), static_cast<uint8_t>(rgb)};
    }
  }
  return m;
}

HealthMessage fromWire(const hxmap_msgs_msg_dds__Health_& w) {
  HealthMessage m;
  m.stamp_ns = fromTime(w.header.stamp);
  m.frame_id = str(w.header.frame_id);
  m.frames = w.frames;
  m.frames_dropped = w.frames_dropped;
  m.frames_lost = w.frames_lost;
  m.deadline_misses = w.deadline_misses;
  m.keyframes = w.keyframes;
  m.refine_jobs_done = w.refine_jobs_done;
  m.refine_jobs_shed = w.refine_jobs_shed;
  m.messages_dropped = w.messages_dropped;
  m.fps = w.fps;
  m.latency_ms_p50 = w.latency_ms_p50;
  m.latency_ms_max = w.latency_ms_max;
  m.frontend_ms_p50 = w.frontend_ms_p50;
  return m;
}

std::vector<TransformMessage> fromWire(const tf2_msgs_msg_dds__TFMessage_& w) {
  std::vector<TransformMessage> out;
  for (uint32_t i = 0; i < w.transforms._length; ++i) {
    const auto& t = w.transforms._buffer[i];
    TransformMessage m;
    m.stamp_ns = fromTime(t.header.stamp);
    m.frame_id = str(t.header.frame_id);
    m.child_frame_id = str(t.child_frame_id);
    const auto& x = t.transform.translation;
    m.T_parent_child = fromPose({x.x, x.y, x.z}, t.transform.rotation);
    out.push_back(std::move(m));
  }
  return out;
}

std::string describe(const TransformMessage& m) {
  const Eigen::Vector3d t = m.T_parent_child.translation();
  const Eigen::Quaterniond q(m.T_parent_child.linear());
  return fmt::format("tf {} {} -> {} t {:.6f} {:.6f} {:.6f} q {:.6f} {:.6f} {:.6f} {:.6f}", stampText(m.stamp_ns),
                     m.frame_id, m.child_frame_id, t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w());
}

std::string describe(const PoseMessage& m) {
  const Eigen::Vector3d t = m.T_world_cam.translation();
  const Eigen::Quaterniond q(m.T_world_cam.linear());
  return fmt::format("pose {} {} t {:.6f} {:.6f} {:.6f} q {:.6f} {:.6f} {:.6f} {:.6f}", stampText(m.stamp_ns), m.frame_id,
                     t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w());
}

std::string describe(const PathMessage& m) {
  std::string last;
  if (!m.poses.empty()) {
    const Eigen::Vector3d t = m.poses.back().T_world_cam.translation();
    last = fmt::format(" last {} t {:.6f} {:.6f} {:.6f}", stampText(m.poses.back().stamp_ns), t.x(), t.y(), t.z());
  }
  return fmt::format("trajectory {} {} poses {}{}", stampText(m.stamp_ns), m.frame_id, m.poses.size(), last);
}

std::string describe(const MapChunkMessage& m) {
  return fmt::format("map {} {} region {} {} {} part {}/{} revision {} vertices {} triangles {} colors {} bytes {}",
                     stampText(m.stamp_ns), m.frame_id, m.region.x(), m.region.y(), m.region.z(), m.part, m.parts,
                     m.revision, m.vertices.size() / 3, m.triangles.size() / 3, m.colors.empty() ? "no" : "yes",
                     m.payloadBytes());
}

std::string describe(const std::vector<MarkerMessage>& markers) {
  size_t added = 0, deleted = 0, triangles = 0, bytes = 0;
  for (const auto& m : markers) {
    (m.action == MarkerMessage::kDelete ? deleted : added) += 1;
    if (m.type == MarkerMessage::kTriangleList) triangles += m.points.size() / 3;
    bytes += m.payloadBytes();
  }
  return fmt::format("markers {} {} added {} deleted {} triangles {} bytes {}",
                     markers.empty() ? "0.000000000" : stampText(markers.front().stamp_ns),
                     markers.empty() ? "" : markers.front().frame_id, added, deleted, triangles, bytes);
}

std::string describe(const OdometryMessage& m) {
  const Eigen::Vector3d t = m.T_parent_child.translation();
  const Eigen::Quaterniond q(m.T_parent_child.linear());
  return fmt::format(
      "odom {} {} -> {} {:.6f} {:.6f} {:.6f} {:.6f} {:.6f} {:.6f} {:.6f} linear {:.4f} {:.4f} {:.4f} "
      "angular {:.4f} {:.4f} {:.4f}",
      stampText(m.stamp_ns), m.frame_id, m.child_frame_id, t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w(),
      m.linear.x(), m.linear.y(), m.linear.z(), m.angular.x(), m.angular.y(), m.angular.z());
}

std::string describe(const PointCloudMessage& m) {
  return fmt::format("cloud {} {} points {} colors {} bytes {}", stampText(m.stamp_ns), m.frame_id, m.points.size(),
                     m.colors.empty() ? "no" : "yes", m.payloadBytes());
}

std::string describe(const HealthMessage& m) {
  return fmt::format("health {} frames {} dropped {} lost {} misses {} keyframes {} refine_done {} refine_shed {} "
                     "messages_dropped {} fps {:.2f} latency_p50_ms {:.2f} latency_max_ms {:.2f} frontend_p50_ms {:.2f}",
                     stampText(m.stamp_ns), m.frames, m.frames_dropped, m.frames_lost, m.deadline_misses, m.keyframes,
                     m.refine_jobs_done, m.refine_jobs_shed, m.messages_dropped, m.fps, m.latency_ms_p50,
                     m.latency_ms_max, m.frontend_ms_p50);
}

}  // namespace hxmap::rt::dds
