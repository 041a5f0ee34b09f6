// hxmap's topics: names, QoS, and the C++ form of each message with its
// conversion to and from the idlc-generated wire structs.
//
//   rt/<prefix>/pose        geometry_msgs/PoseStamped  reliable, volatile, keep last 10
//   rt/<prefix>/odom        nav_msgs/Odometry          reliable, volatile, keep last 10
//   rt/<prefix>/trajectory  nav_msgs/Path              reliable, transient local, keep last 1
//   rt/<prefix>/map         visualization_msgs/MarkerArray  reliable, keep all (no update replaced
//                           before delivery), transient local with the newest 1;
//                           the whole map again whenever a reader joins
//   rt/<prefix>/map_cloud   sensor_msgs/PointCloud2    reliable, transient local, keep last 1: the whole
//                           map's surface points (x, y, z, rgb) every map update
//   rt/<prefix>/map_chunks  hxmap_msgs/MapChunk        reliable, transient local, keep last 1 per (region, part)
//   rt/<prefix>/health      hxmap_msgs/Health          reliable, transient local, keep last 1
//   rt/tf                   tf2_msgs/TFMessage         reliable, volatile, keep last 100 (as tf2's broadcaster)
//
// "rt/" is how ROS 2 names a topic on the DDS wire, and the type names are
// ROS 2's (geometry_msgs::msg::dds_::PoseStamped_ ...), so `ros2 topic echo
// /hxmap/pose` works without any ROS code in hxmap. Stamps are the capture
// time of the frame, in the sensor's clock. Poses are camera-to-map.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/core/frame.hpp"
#include "hxmap/dds/entity.hpp"
#include "hxmap_msgs.h"

namespace hxmap::rt::dds {

enum class Topic { kPose, kOdom, kTrajectory, kMap, kMapChunks, kMapCloud, kHealth, kTf, kTfStatic };
inline constexpr Topic kAllTopics[] = {Topic::kPose,   Topic::kOdom,      Topic::kTrajectory,
                                       Topic::kMap,    Topic::kMapChunks, Topic::kMapCloud,
                                       Topic::kHealth, Topic::kTf,        Topic::kTfStatic};

/// "rt/<prefix>/pose" and so on; TF is ROS 2's one "rt/tf" whatever the prefix.
std::string topicName(Topic topic, const std::string& prefix);
/// Topic by its short name ("pose", "odom", "trajectory", "map", "map_chunks", "map_cloud", "health", "tf",
/// "tf_static").
Expected<Topic> topicFromString(const std::string& name);
const char* topicShortName(Topic topic);
TopicQos topicQos(Topic topic);
const dds_topic_descriptor_t* topicType(Topic topic);

struct PoseMessage {
  int64_t stamp_ns = 0;
  std::string frame_id;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
};

/// One transform of /tf: `child_frame_id`'s pose in `frame_id`.
struct TransformMessage {
  int64_t stamp_ns = 0;
  std::string frame_id, child_frame_id;
  Eigen::Isometry3d T_parent_child = Eigen::Isometry3d::Identity();
};

/// nav_msgs/Odometry: `child_frame_id`'s pose in `frame_id` and its
/// velocity in `child_frame_id` (covariances are not estimated: sent as 0).
struct OdometryMessage {
  int64_t stamp_ns = 0;
  std::string frame_id, child_frame_id;
  Eigen::Isometry3d T_parent_child = Eigen::Isometry3d::Identity();
  Eigen::Vector3d linear = Eigen::Vector3d::Zero();   ///< m/s
  Eigen::Vector3d angular = Eigen::Vector3d::Zero();  ///< rad/s
};

struct PathMessage {
  int64_t stamp_ns = 0;
  std::string frame_id;
  Trajectory poses;
};

struct MapChunkMessage {
  int64_t stamp_ns = 0;
  std::string frame_id;
  Eigen::Vector3i region = Eigen::Vector3i::Zero();
  uint16_t part = 0, parts = 0;
  uint32_t revision = 0;
  float region_size_m = 0;
  std::vector<float> vertices;     ///< x, y, z per vertex
  std::vector<uint8_t> colors;     ///< r, g, b per vertex, or empty
  std::vector<uint32_t> triangles; ///< 3 indices per triangle
  /// Bytes of payload (what bandwidth figures count).
  size_t payloadBytes() const {
    return vertices.size() * sizeof(float) + colors.size() + triangles.size() * sizeof(uint32_t);
  }
};

/// One visualization_msgs/Marker of the map: a TRIANGLE_LIST (3 points
/// per triangle, a color per point) added or replaced under (ns, id), or
/// the DELETE of one.
struct MarkerMessage {
  static constexpr int32_t kTriangleList = 11;
  static constexpr int32_t kAdd = 0, kDelete = 2;
  int64_t stamp_ns = 0;
  std::string frame_id;
  std::string ns;
  int32_t id = 0;
  int32_t type = kTriangleList;
  int32_t action = kAdd;
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector4f> colors;  ///< r, g, b, a in [0, 1] per point, or empty
  /// Bytes of the points and colors as they go on the wire.
  size_t payloadBytes() const { return points.size() * 3 * sizeof(double) + colors.size() * 4 * sizeof(float); }
};

/// A sensor_msgs/PointCloud2 of colored points: fields x, y, z (float32)
/// and rgb (a float32 holding 0x00RRGGBB, as PCL and RViz read it), 16
/// bytes a point, one row.
struct PointCloudMessage {
  int64_t stamp_ns = 0;
  std::string frame_id;
  std::vector<Eigen::Vector3f> points;
  std::vector<std::array<uint8_t, 3>> colors;  ///< one per point, or empty (then white)
  size_t payloadBytes() const { return points.size() * 16; }
};

struct HealthMessage {
  int64_t stamp_ns = 0;
  std::string frame_id;
  uint64_t frames = 0, frames_dropped = 0, frames_lost = 0, deadline_misses = 0, keyframes = 0;
  uint64_t refine_jobs_done = 0, refine_jobs_shed = 0, messages_dropped = 0;
  float fps = 0, latency_ms_p50 = 0, latency_ms_max = 0, frontend_ms_p50 = 0;
};

// To the wire: the structs point into the message (no copies); they are
// valid while the message lives and is not modified.
struct PoseWire {
  explicit PoseWire(const PoseMessage& m);
  geometry_msgs_msg_dds__PoseStamped_ wire{};
};
struct OdometryWire {
  explicit OdometryWire(const OdometryMessage& m);
  nav_msgs_msg_dds__Odometry_ wire{};
};
struct PathWire {
  explicit PathWire(const PathMessage& m);
  std::vector<geometry_msgs_msg_dds__PoseStamped_> poses;
  nav_msgs_msg_dds__Path_ wire{};
};
struct MapChunkWire {
  explicit MapChunkWire(const MapChunkMessage& m);
  hxmap_msgs_msg_dds__MapChunk_ wire{};
};
struct MarkerArrayWire {
  explicit MarkerArrayWire(const std::vector<MarkerMessage>& markers);
  std::vector<visualization_msgs_msg_dds__Marker_> markers;
  std::vector<std::vector<geometry_msgs_msg_dds__Point_>> points;
  std::vector<std::vector<std_msgs_msg_dds__ColorRGBA_>> colors;
  visualization_msgs_msg_dds__MarkerArray_ wire{};
};
struct PointCloudWire {
  explicit PointCloudWire(const PointCloudMessage& m);
  std::vector<sensor_msgs_msg_dds__PointField_> fields;
  std::vector<uint8_t> data;
  sensor_msgs_msg_dds__PointCloud2_ wire{};
};
struct TfWire {
  explicit TfWire(const std::vector<TransformMessage>& m);
  std::vector<geometry_msgs_msg_dds__TransformStamped_> transforms;
  tf2_msgs_msg_dds__TFMessage_ wire{};
};
struct HealthWire {
  explicit HealthWire(const HealthMessage& m);
  hxmap_msgs_msg_dds__Health_ wire{};
};

// From the wire (copies). A chunk whose sequences disagree (colors not 3
// per vertex, an index out of range) is an Error naming what is wrong.
PoseMessage fromWire(const geometry_msgs_msg_dds__PoseStamped_& w);
PathMessage fromWire(const nav_msgs_msg_dds__Path_& w);
OdometryMessage fromWire(const nav_msgs_msg_dds__Odometry_& w);
Expected<MapChunkMessage> fromWire(const hxmap_msgs_msg_dds__MapChunk_& w);
/// A marker whose colors are neither none nor one per point, or a triangle
/// list whose points are not a multiple of 3, is an Error.
Expected<std::vector<MarkerMessage>> fromWire(const visualization_msgs_msg_dds__MarkerArray_& w);
/// Any PointCloud2 with float32 x, y, z fields (and rgb when present);
/// sizes that disagree with the data are an Error.
Expected<PointCloudMessage> fromWire(const sensor_msgs_msg_dds__PointCloud2_& w);
HealthMessage fromWire(const hxmap_msgs_msg_dds__Health_& w);
std::vector<TransformMessage> fromWire(const tf2_msgs_msg_dds__TFMessage_& w);

/// One line of text per message, as `hxmap echo` prints them.
std::string describe(const PoseMessage& m);
std::string describe(const PathMessage& m);
std::string describe(const OdometryMessage& m);
std::string describe(const MapChunkMessage& m);
std::string describe(const std::vector<MarkerMessage>& markers);
std::string describe(const PointCloudMessage& m);
std::string describe(const HealthMessage& m);
std::string describe(const TransformMessage& m);

}  // namespace hxmap::rt::dds
