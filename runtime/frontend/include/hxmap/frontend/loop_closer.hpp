// Loop closure (paper: "the explicit backbone ensures compatibility with
// loop closure"): a pose graph over keyframes, place recognition over its
// own keyframe database, verification by ICP against a map fused from the
// keyframes alone, and, for an accepted closure, that map fused anew at
// the keyframes' new poses.
//
// DESIGN: the loop closer owns everything it reads and writes (graph,
// database, keyframe observations, keyframe map), so it can run on a
// thread of its own without sharing the frontend's map: the frontend sends
// it keyframes and takes back corrections, each carrying a map to swap in.
// Its work is cut into steps of a few milliseconds (matching one
// keyframe's descriptors, one PnP, one ICP check, the solve, fusing two
// observations) so the real-time runtime runs one step per slice its
// scheduler admits; offline, the frontend runs every step at once.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/se3.hpp"
#include "hxmap/posegraph/params.hpp"
#include "hxmap/posegraph/pose_graph.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/relocalization/keyframe_database.hpp"
#include "hxmap/tracking/icp.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/raycast.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt {

/// What loop closure did, summed over a run.
struct LoopClosureCounters {
  uint64_t keyframes = 0;      ///< keyframes the graph received
  uint64_t queries = 0;        ///< keyframes compared with the old ones
  uint64_t skipped = 0;        ///< not compared: a newer keyframe was already waiting
  uint64_t late_keyframes = 0;  ///< made before the frontend applied a correction sent earlier (moved by it here)
  uint64_t shed = 0;           ///< comparisons given up, or keyframes taken in unchecked, for lack of CPU (real time)
  uint64_t candidates = 0;     ///< PnP poses from old keyframes
  uint64_t refused_drift = 0;  ///< candidates farther from the tracked pose than odometry can drift
  uint64_t refused_icp = 0;    ///< candidates ICP against the keyframe map did not confirm
  uint64_t refused_graph = 0;  ///< confirmed ones the pose graph could not take (chi-square)
  uint64_t consistent = 0;     ///< confirmed, the graph moved no keyframe beyond min_correction: nothing applied
  uint64_t odometry_jumps = 0;       ///< tracked motion between keyframes their own alignment disagreed with (replaced)
  uint64_t odometry_unverified = 0;  ///< keyframe-to-keyframe alignments that failed (tracked motion kept)
  uint64_t odometry_unchecked = 0;   ///< tracked motion taken unchecked (the closer was behind)
  uint64_t closures = 0;       ///< confirmed and solved: a correction with a rebuilt map sent
  uint64_t applied = 0;        ///< corrections the frontend applied (trajectory corrected, map swapped)
  uint64_t keyframes_rebuilt = 0;  ///< keyframe observations re-fused, summed over rebuilds
  uint64_t stale_refinements = 0;  ///< refinement results for a map since rebuilt (dropped)
  double largest_correction_m = 0, largest_correction_deg = 0;  ///< the most any keyframe moved in a closure
  double cost_before = 0, cost_after = 0;  ///< pose graph cost, summed over closures
  double detect_ms = 0, solve_ms = 0, rebuild_ms = 0, fuse_ms = 0;  ///< totals (fuse: the keyframe map)
  /// Under a memory budget: the keyframe map's blocks moved out to its
  /// store and brought back (for a comparison in their view), and its
  /// largest resident size once a keyframe is in.
  uint64_t blocks_moved_out = 0, blocks_brought_back = 0, blocks_lost = 0;
  size_t map_bytes_max = 0;
};

/// A keyframe for the loop closer, from the frontend. Images are shared
/// with the frontend's frame (never written after it is made).
struct LoopKeyframe {
  uint32_t id = 0;
  uint64_t epoch = 0;  ///< corrections the frontend had applied when it made this keyframe
  Eigen::Isometry3d T_world_kf = Eigen::Isometry3d::Identity();
  /// The previous keyframe (id - 1) as tracking left it, for the odometry
  /// factor (none for the first keyframe): its frame, its depth camera's
  /// and its color camera's poses.
  std::optional<alg::PreprocessedFrame> previous;
  Eigen::Isometry3d T_world_previous = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_world_previous_color = Eigen::Isometry3d::Identity();
  /// This frame's color camera relative to its depth camera, and the
  /// photometric scale tracking used (for the keyframe-to-keyframe check).
  Eigen::Isometry3d T_depth_color = Eigen::Isometry3d::Identity();
  double photometric_scale_m = 0;
  alg::FrameFeatures features;
  /// Real time: `features` are still to be made from `frame`, off the
  /// frontend's thread (describeKeyframe), and go back to the frontend's
  /// keyframe database as well.
  bool describe = false;
  /// For the loop closer (false: only to be described, loop closure off).
  bool close = true;
  alg::PreprocessedFrame frame;       ///< for ICP against the keyframe map
  alg::DepthObservation observation;  ///< what the keyframe map fuses (pose: T_world_kf)
};

/// The keyframe with images of its own: every image deep-copied (a buffer
/// that several images share is copied once). A real-time loop closer
/// thread calls it on each keyframe it takes from the frontend, so that the
/// frontend's buffers are free again at once and the copies' first-touch
/// page faults are paid on the background thread, not by the frontend's
/// next frame.
LoopKeyframe withOwnImages(LoopKeyframe kf);

/// A keyframe's ORB features made off the frontend's thread, for its
/// keyframe database, and what making them cost.
struct KeyframeFeatures {
  uint32_t id = 0;
  alg::FrameFeatures features;
  double ms = 0;
};

/// Makes `kf.features` from its frame's intensity and depth (what the
/// frontend's keyframe database would have made) and returns a copy of
/// them for the frontend; clears `kf.describe`.
KeyframeFeatures describeKeyframe(LoopKeyframe& kf, const alg::RelocalizationParams& params);

/// An accepted closure, for the frontend to apply between frames.
struct LoopCorrection {
  uint64_t epoch = 0;  ///< the frontend's correction count once applied (the first is 1)
  uint32_t keyframe = 0, matched = 0;   ///< the closing keyframe and the old one it met
  std::map<uint32_t, Eigen::Isometry3d> nodes;  ///< every keyframe's pose after the solve
  /// T_after * T_before^-1 of the newest keyframe: what moves the frames
  /// after it (and the live pose).
  Eigen::Isometry3d newest = Eigen::Isometry3d::Identity();
  /// The map fused from the stored keyframe observations at their new
  /// poses (frames fused since the closing keyframe are not in it).
  std::shared_ptr<alg::TsdfMap> map;
};

struct LoopCloserParams {
  alg::LoopClosureParams loop;
  alg::RelocalizationParams relocalization;
  alg::TrackingParams tracking;
  alg::TsdfParams tsdf;
  alg::RaycastParams raycast;
  int rebuild_step_keyframes = 2;  ///< observations fused per rebuild step
  size_t max_pending = 16;         ///< queued keyframes beyond which shed() takes the oldest in unchecked
};

class LoopCloser {
 public:
  LoopCloser(const LoopCloserParams& params, const alg::PinholeCamera& camera, ParallelFor parallel = serialFor);

  /// How its data-parallel loops run (serial on a background thread).
  void setParallel(ParallelFor parallel) { parallel_ = std::move(parallel); }
  /// A memory budget for the keyframe map: from 90 % of `budget_bytes` its
  /// blocks farthest from the newest keyframe move out to `backing` (a
  /// store of its own, used from the thread that runs step()), and come
  /// back when a comparison looks at them. Null: no budget.
  void setBlockBacking(alg::BlockBacking* backing, size_t budget_bytes);
  const alg::TsdfMap& keyframeMap() const { return map_; }
  /// Continues a saved map (hxmap run --load-map): its keyframes enter the
  /// graph as nodes no solve moves and the database as candidates, and the
  /// map is what this run's keyframes are checked against and, after a
  /// closure, fused onto (its frames' observations were not saved). The
  /// first keyframe taken in after seeding is fixed too: relocalization put
  /// it in the saved map, and it anchors this run's chain until a closure
  /// ties the chain to the old keyframes. Called before any add().
  void seed(const alg::TsdfMap& map, const alg::KeyframeDatabase& keyframes);
  /// Queues a keyframe; step() takes it in once the work before it is done.
  void add(LoopKeyframe keyframe) { pending_.push_back(std::move(keyframe)); }
  /// Runs the next step; false when there was nothing to do.
  bool step();
  /// Work left (queued keyframes or a step in progress).
  bool busy() const { return phase_ != Phase::kIdle || !pending_.empty(); }
  /// The scheduler shed the work: a comparison under way is given up, or,
  /// past max_pending queued keyframes, the oldest take their places in
  /// the graph at once (tracked motion unchecked, not compared, not fused
  /// into the keyframe map). False when nothing could be given up (a
  /// rebuild, once the graph has moved, never is).
  bool shed();
  /// In the middle of a rebuild (its steps must not be shed).
  bool rebuilding() const { return phase_ == Phase::kRebuild; }
  std::optional<LoopCorrection> takeCorrection() { return std::exchange(correction_, std::nullopt); }

  const LoopClosureCounters& counters() const { return counters_; }
  const alg::PoseGraph& graph() const { return graph_; }
  const alg::KeyframeDatabase& database() const { return database_; }
  /// Keyframe observations stored for rebuilds, and their bytes.
  std::pair<size_t, size_t> observations() const;

 private:
  enum class Phase { kIdle, kQuery, kVerify, kSolve, kRebuild };
  /// The next queued keyframe into the graph and database; its query
  /// begins unless it is behind (another waits) or `shed`.
  void begin(bool shed = false);
  /// The keyframe's observation into the keyframe map (unless !fuse); the
  /// phase ends.
  void finishKeyframe(bool fuse = true);
  /// Tracking's motion between the keyframes, as it is (counted).
  Eigen::Isometry3d uncheckedOdometry(const LoopKeyframe& kf);
  /// Odometry from the previous keyframe to this one: the tracked motion,
  /// checked by aligning the keyframe to the previous one's own depth and
  /// color; where the two disagree beyond loop.odometry_sigma_* (times
  /// jump_sigmas), the alignment. DESIGN: tracking against the map snaps
  /// back onto old surfaces when the camera returns to them; that jump in
  /// the chain would hide the drift the loop should spread out. Always the
  /// alignment was worse: on the quality room its errors added up to a
  /// 3 cm closure that tracking (0.12 cm ATE) did not need.
  Eigen::Isometry3d odometry(const LoopKeyframe& kf);
  void verifyNext();
  void solve();
  void rebuildStep();
  /// Meters between consecutive keyframes of the graph from `from` to `to`.
  double pathLength(uint32_t from, uint32_t to) const;
  std::vector<alg::ModelView> render(const alg::PreprocessedFrame& frame, const Eigen::Isometry3d& T_world_cam);
  /// Under a budget: the keyframe map's blocks out of memory that a camera
  /// at T_world_cam sees come back; then, from 90 % of the budget, the
  /// farthest from it move out.
  void bringBackView(const Eigen::Isometry3d& T_world_cam);
  void keepWithinBudget(const Eigen::Isometry3d& T_world_cam);

  LoopCloserParams params_;
  alg::PinholeCamera camera_;
  ParallelFor parallel_;
  alg::PoseGraph graph_;
  alg::KeyframeDatabase database_;
  alg::TsdfMap map_;  ///< the stored keyframes fused at their graph poses (onto base_)
  /// A saved map this run continues (seed()): what a rebuild starts from.
  std::shared_ptr<const alg::TsdfMap> base_;
  bool fix_next_ = false;  ///< the next keyframe is the first after seed()
  alg::BlockBacking* backing_ = nullptr;
  size_t budget_bytes_ = 0;
  std::map<uint32_t, alg::DepthObservation> observations_;
  /// Per correction sent: its `newest` (keyframes made before the frontend
  /// applied it arrive in the old frame and are moved by it here).
  std::vector<Eigen::Isometry3d> corrections_;
  std::deque<LoopKeyframe> pending_;
  Phase phase_ = Phase::kIdle;
  LoopKeyframe current_;  ///< the keyframe being compared
  std::optional<alg::KeyframeQuery> query_;
  std::vector<alg::RelocalizationCandidate> candidates_;
  size_t next_candidate_ = 0;
  struct Confirmed {
    alg::RelocalizationCandidate candidate;
    Eigen::Isometry3d T_world_kf;
    alg::Matrix6d information;  ///< ICP's, world frame, left perturbation
  };
  std::optional<Confirmed> confirmed_;
  std::optional<alg::TsdfMap> rebuilt_;
  std::vector<uint32_t> rebuild_ids_;
  size_t rebuild_next_ = 0;
  LoopCorrection building_;  ///< the correction whose map is being rebuilt
  std::optional<LoopCorrection> correction_;
  LoopClosureCounters counters_;
};

}  // namespace hxmap::rt
