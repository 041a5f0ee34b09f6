// Publishes what the mapping runtime produces on hxmap's DDS topics
// (messages.hpp): the pose of every frame, the trajectory, map updates as
// meshes of the regions that changed, and health.
//
// DESIGN: the frontend thread calls onFrame() after each frame. The pose is
// written right there: a write of 100 bytes to a keep-last writer never
// blocks (reliable or not, the oldest unacknowledged sample is replaced)
// and costs microseconds, and any hand-over to another thread would only add
// latency. Everything else leaves the frontend thread as a work item on an
// SPSC ring to the publisher thread (hx-publish), on its period: for the map
// the frontend copies the blocks of the regions changed since the last
// update (bounded by what changed, not by the map), and the publisher thread
// meshes them and writes them twice: one MarkerArray per update, a marker
// per region part (RViz and any ROS 2 node read it), and one compact
// MapChunk per region part (keyed, for hxmap's own readers).
//
// A PointCloud2 of the whole map's surface points (the region meshes'
// vertices with their colors) follows every update: 16 bytes a point, so
// it is small enough to be a state that late joiners get as it is.
//
// The MarkerArray topic is keyless: a reader that keeps one sample (or
// lags) holds only the newest, so each sample is a whole update, and a
// reader that joins late would get only the last update. The publisher
// thread therefore watches the map writer's matched readers and, when one
// joined, sends the whole map again as one sample from the region meshes
// it keeps (about the size of the mesh): a late joiner has the whole map
// within one health period after its discovery, and the readers already
// there receive the same markers again, which replace themselves. A full ring drops the
// item, counted; the regions stay marked as changed and go out next time, so
// no map data is lost, only delayed. Reliable writers may block the
// publisher thread (a slow reliable reader), never the frontend.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "hxmap/core/expected.hpp"
#include "hxmap/core/frame.hpp"
#include "hxmap/dds/messages.hpp"
#include "hxmap/frontend/results.hpp"
#include "hxmap/ring/spsc_ring.hpp"
#include "hxmap/tsdf/map_regions.hpp"
#include "hxmap/tsdf/params.hpp"

namespace hxmap::rt::dds {

struct PublisherParams {
  uint32_t domain_id = 0;
  std::string topic_prefix = "hxmap";
  std::string frame_id = "map";
  /// The camera's frame on /tf (frame_id -> child_frame_id, the optical
  /// convention: z forward, x right, y down, per REP 103's _optical suffix).
  std::string child_frame_id = "hxmap_camera_optical_frame";
  /// With a robot base (REP 105): /tf carries frame_id -> base_frame_id per
  /// tracked frame and /tf_static base_frame_id -> child_frame_id once
  /// (T_base_cam, the optical frame in the base's). Empty: the camera
  /// itself goes on /tf.
  std::string base_frame_id;
  /// An odometry frame (REP 105; e.g. "odom"): /tf carries frame_id ->
  /// odom_frame_id (loop closures' corrections) and odom_frame_id -> the
  /// base or camera (continuous). Empty: frame_id -> base or camera.
  std::string odom_frame_id;
  Eigen::Isometry3d T_base_cam = Eigen::Isometry3d::Identity();
  /// Added to every stamp sent: 0 for recordings (their recorded stamps);
  /// for live cameras, whose stamps are CLOCK_MONOTONIC, the offset of
  /// CLOCK_REALTIME from it, so that stamps are in the ROS clock's epoch.
  int64_t stamp_offset_ns = 0;
  double map_period_s = 1.0;         ///< changed regions go out at most this often
  double trajectory_period_s = 1.0;
  /// The Path carries the newest this many poses (0: all; the whole
  /// trajectory grows without bound and is copied on the frontend thread
  /// every period).
  int path_max_poses = 900;
  double health_period_s = 1.0;
  int region_blocks = 4;             ///< region side in TSDF blocks
  int max_triangles_per_chunk = 16384;
  int queue_capacity = 16;           ///< work items between the frontend and the publisher thread
  double flush_ack_timeout_s = 2.0;  ///< flush() waits this long at most for reliable readers' acknowledgments
  alg::MeshParams mesh;
  /// Under a memory budget: copies a block held out of memory (the block
  /// store's peek; called on hx-publish). Null: a changed region with such
  /// blocks waits until they are back in memory.
  alg::BlockReader read_elsewhere;
};


struct PublisherStats {
  uint64_t poses = 0, transforms = 0, paths = 0, health = 0;
  uint64_t map_updates = 0;     ///< snapshots meshed and written
  uint64_t regions = 0;         ///< region meshes written
  /// Changed regions held back at an update because some of their blocks
  /// were out of memory (a memory budget), summed over updates.
  uint64_t region_waits = 0;
  uint64_t regions_waiting = 0;  ///< of which still held back now
  /// With read_elsewhere: blocks out of memory read for a region's mesh,
  /// and regions held back because one of them no longer read (taken back
  /// into memory since the update; the region goes out with the next).
  uint64_t blocks_read_elsewhere = 0, region_retries = 0;
  uint64_t chunks = 0;          ///< chunk samples written (empty ones included)
  uint64_t chunk_bytes = 0;     ///< their payload (vertices, colors, indices)
  uint64_t marker_arrays = 0;   ///< MarkerArray samples written on the map topic (one per update)
  uint64_t marker_bytes = 0;    ///< their payload (points, colors)
  uint64_t map_resends = 0;     ///< whole-map MarkerArrays sent because a reader joined
  uint64_t clouds = 0;          ///< whole-map PointCloud2 samples (one per update)
  uint64_t cloud_bytes = 0;     ///< their point data
  uint64_t last_cloud_points = 0;
  uint64_t ack_timeouts = 0;    ///< flushes whose data some reliable reader had not acknowledged in time
  uint64_t items_dropped = 0;   ///< work items the full ring refused (data delayed, not lost)
  uint64_t write_errors = 0;
  std::string last_error;
  double frame_cost_p50_ms = 0, frame_cost_max_ms = 0;  ///< onFrame on the calling thread (recent frames)
  double snapshot_ms_total = 0;                         ///< of which copying changed regions
  double mesh_ms_total = 0;                             ///< publisher thread: meshing and writing chunks
};

class Publisher {
 public:
  /// Joins the domain, creates a writer per topic and starts hx-publish.
  static Expected<std::unique_ptr<Publisher>> start(const PublisherParams& params);
  ~Publisher();
  Publisher(const Publisher&) = delete;
  Publisher& operator=(const Publisher&) = delete;

  /// Frontend thread, after each processed frame.
  void onFrame(const FrameResult& result, const alg::TsdfMap& map, const Trajectory& trajectory,
               const RunCounters& counters);
  /// Same thread: publishes every region changed since the last update, the
  /// whole trajectory and health now, and returns once they are written and
  /// the reliable readers have acknowledged them (at most
  /// flush_ack_timeout_s; end of a run, tests).
  void flush(const alg::TsdfMap& map, const Trajectory& trajectory, const RunCounters& counters);

  /// Calling thread; consistent after flush().
  PublisherStats stats() const;
  const PublisherParams& params() const { return params_; }
  uint32_t matchedReaders(Topic topic) const;

 private:
  struct Work;
  explicit Publisher(const PublisherParams& params);
  bool push(std::unique_ptr<Work> work, bool must);
  void snapshotMap(const alg::TsdfMap& map, int64_t stamp_ns, bool must);
  void queuePath(const Trajectory& trajectory, int64_t stamp_ns, bool must);
  void queueHealth(const RunCounters& counters, int64_t stamp_ns, bool must);
  void run();
  void process(Work& work);
  /// Writes the region's chunks and appends its markers to `markers`.
  void writeRegion(const alg::TsdfMap& snapshot, const alg::RegionKey& region, int64_t stamp_ns,
                   std::vector<MarkerMessage>& markers);
  void writeMarkers(const std::vector<MarkerMessage>& markers);
  void resendMapToNewReaders();
  /// The surface points of every region as last sent, as one PointCloud2.
  void writeCloud(int64_t stamp_ns);
  void recordError(const Status& s);

  PublisherParams params_;
  Participant participant_;
  std::vector<Writer> writers_;  ///< by Topic
  SpscRing<std::unique_ptr<Work>> ring_;
  std::atomic<uint32_t> work_seq_{0};
  std::atomic<uint32_t> flushed_seq_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;

  // Calling thread.
  uint64_t map_revision_ = 0;
  std::unordered_map<uint64_t, alg::RegionKey> sent_regions_;  ///< regions handed to hx-publish, still in the map
  /// Changed regions with blocks out of memory: sent once they are back.
  std::unordered_map<uint64_t, alg::RegionKey> waiting_regions_;
  uint64_t region_waits_ = 0;
  std::optional<OdometryMessage> last_odom_;  ///< the previous frame's, for the velocity
  int64_t last_map_ns_ = 0, last_path_ns_ = 0, last_health_ns_ = 0;
  uint32_t flush_count_ = 0;
  std::vector<double> frame_cost_ms_;
  double snapshot_ms_total_ = 0;
  std::vector<double> period_latency_ms_, period_frontend_ms_;
  uint64_t frames_ = 0, frames_lost_ = 0, keyframes_ = 0, period_frames_ = 0;
  uint64_t poses_ = 0, transforms_ = 0, items_dropped_ = 0, ack_timeouts_ = 0;

  // Publisher thread (read by stats() after a flush).
  struct RegionState {
    uint32_t revision = 0;
    uint16_t parts = 0;
    std::vector<alg::TriangleMesh> meshes;  ///< the parts as last sent, for readers that join later
    std::vector<int32_t> marker_ids;        ///< marker id of each part (stable; ids are never reused)
  };
  std::unordered_map<uint64_t, RegionState> regions_;
  int32_t next_marker_id_ = 0;
  int64_t last_map_stamp_ns_ = 0;
  uint32_t map_readers_seen_ = 0;  ///< the map writer's matched readers, counted over the run
  bool resend_all_ = false;        ///< a MarkerArray write failed: send the whole map again
  std::atomic<uint64_t> paths_{0}, health_{0}, map_updates_{0}, regions_written_{0}, chunks_{0}, chunk_bytes_{0};
  std::atomic<uint64_t> marker_arrays_{0}, marker_bytes_{0}, map_resends_{0}, clouds_{0}, cloud_bytes_{0},
      last_cloud_points_{0};
  std::atomic<uint64_t> write_errors_{0};
  std::atomic<uint64_t> blocks_read_elsewhere_{0}, region_retries_{0};
  /// Regions hx-publish could not complete (a block did not read): the
  /// calling thread's next update sends them again.
  mutable std::mutex retry_mutex_;
  std::vector<alg::RegionKey> retry_regions_;
  std::atomic<double> mesh_ms_total_{0};
  mutable std::mutex error_mutex_;
  std::string last_error_;
};

}  // namespace hxmap::rt::dds
