// The frontend: the per-frame backbone pipeline (paper 3.1). Owns the TSDF,
// the only writer of it. Not thread safe: one thread calls process().
#pragma once

#include <array>
#include <atomic>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "hxmap/core/frame.hpp"
#include "hxmap/core/parallel.hpp"
#include "hxmap/feedback/field_surface.hpp"
#include "hxmap/feedback/params.hpp"
#include "hxmap/feedback/window.hpp"
#include "hxmap/frontend/loop_closer.hpp"
#include "hxmap/frontend/results.hpp"
#include "hxmap/implicit/refine.hpp"
#include "hxmap/pose_feedback/feedback_solver.hpp"
#include "hxmap/posegraph/params.hpp"
#include "hxmap/posegraph/pose_graph.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/quality/quality.hpp"
#include "hxmap/refine/refine_job.hpp"
#include "hxmap/relocalization/keyframe_database.hpp"
#include "hxmap/tracking/icp.hpp"
#include "hxmap/tracking/state.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "hxmap/tsdf/raycast.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt {

struct FrontendParams {
  alg::PreprocessParams preprocess;
  alg::TsdfParams tsdf;
  alg::RaycastParams raycast;
  alg::TrackingParams tracking;
  /// The keyframe database (ORB features of every keyframe) and
  /// relocalization against it when tracking is lost.
  alg::RelocalizationParams relocalization;
  alg::QualityParams quality;
  bool quality_enabled = true;  ///< score map regions on keyframes (paper 3.2)
  /// ROI refinement jobs (paper 3.3) from each keyframe's ROIs: the caller
  /// runs them (takeRefineJobs) and hands the outcomes back
  /// (applyRefinement). refine.enabled needs quality_enabled.
  RefineParams refine;
  /// Pose feedback (paper 3.4): each keyframe goes to the window
  /// (takeFeedbackKeyframes) and its corrected poses come back
  /// (applyKeyframeCorrection). feedback.enabled = false: neither.
  alg::FeedbackParams feedback;
  /// Loop closure over the keyframe database: closures verified by ICP
  /// against the map, a pose graph over keyframes, the trajectory corrected
  /// and the map rebuilt from the keyframes at their new poses.
  alg::LoopClosureParams loop_closure;
  /// A run that continues a saved map (resumeMap): frames it may take to
  /// relocalize in it before it gives up; then the saved map is set aside
  /// and a new one starts (resume_new_map_otherwise), or the run is told
  /// to stop (resumeFailed).
  /// The memory budget (tsdf.max_resident_mib) needs a backing
  /// (setBlockBacking): from 90 % of the budget the blocks farthest from the
  /// camera leave memory, down to 80 % of it (max_evictions_per_frame a frame,
  /// or more when that would leave the frame over the budget); blocks held there come back ahead of
  /// the camera (those in the predicted view, nearest first, as many as the
  /// budget has room for) or when fusion reaches them.
  int max_evictions_per_frame = 96;  ///< blocks moved out per frame at most
  int max_prefetch_per_frame = 512;  ///< blocks brought back ahead of the camera per frame at most
  /// Blocks in the predicted view that the backing has not read yet: true
  /// (offline) brings them back at once, read on this thread, so the map is
  /// the same whatever the timing; false (real time: a camera, --realtime)
  /// leaves them to a later frame while the backing reads them ahead
  /// (MemoryCounters::prefetch_not_ready), so no frame waits on the disk
  /// for a block it does not fuse into.
  bool wait_for_blocks = true;
  int resume_relocalize_frames = 90;
  bool resume_new_map_otherwise = false;
  /// Evaluation only: a tracking bias, xi = (omega rad, v m) applied to
  /// every tracked pose on the right (T <- T exp(xi)), to measure how pose
  /// feedback copes with drifting odometry. Zero in any real run.
  Eigen::Matrix<double, 6, 1> odometry_bias = Eigen::Matrix<double, 6, 1>::Zero();
};

/// Process-wide: large buffers come from the heap and heap memory is kept
/// between frames (glibc mmap and trim thresholds raised). DESIGN: image
/// buffers (about 1 MiB each, a dozen per frame) were otherwise mapped
/// fresh from the kernel until glibc's adaptive threshold caught up, and
/// heaps were trimmed back, so the first frames paid a page fault per 4 KiB
/// touched: preprocessing took 27-35 ms for frames 0-3 instead of 5 ms.
/// With memory kept, Frontend::warmUp (run on the frontend's own thread,
/// whose allocator arena it grows) makes the first live frame as fast as
/// the rest. Call once at start-up.
void keepHeapBetweenFrames();

class Frontend {
 public:
  Frontend(const alg::PinholeCamera& camera, const FrontendParams& params, ParallelFor parallel = serialFor);

  /// Pose of the first frame (default identity).
  void setInitialPose(const Eigen::Isometry3d& T_world_cam) { T_initial_ = T_world_cam; }

  /// Continues a saved map (hxmap run --load-map), before the first frame:
  /// frames are lost until one relocalizes in it through the saved keyframe
  /// database (verified by ICP against the map, as any relocalization);
  /// nothing is fused before. Loop closure goes on against the saved
  /// keyframes, which it never moves (LoopCloser::seed); under a memory
  /// budget it is off for such a run.
  void resumeMap(alg::TsdfMap map, alg::KeyframeDatabase keyframes);
  /// Resuming and not relocalized yet.
  bool resuming() const { return resuming_; }
  /// The frame index (from 0) that relocalized in the saved map; -1 before.
  int64_t resumedAtFrame() const { return resumed_at_frame_; }
  /// Not relocalized within resume_relocalize_frames with
  /// resume_new_map_otherwise off: the run should stop. Safe from any thread.
  bool resumeFailed() const { return resume_failed_.load(); }
  /// The saved map was set aside for a new one (resume_new_map_otherwise).
  bool resumeAbandoned() const { return resume_abandoned_; }

  /// Where blocks go past the memory budget (not owned; outlives the
  /// frontend's use of the map). Before the first frame.
  void setBlockBacking(alg::BlockBacking* backing) {
    backing_ = backing;
    map_.setBacking(backing);
  }
  /// Where loop closure's keyframe map puts its blocks past a quarter of
  /// the memory budget (a store of its own; not owned). Before the first
  /// frame. DESIGN: the keyframe map covers the whole path like the map
  /// itself; without its own budget a long run's memory grew with it.
  void setLoopBlockBacking(alg::BlockBacking* backing) {
    loop_backing_ = backing;
    if (loop_closer_) loop_closer_->setBlockBacking(loop_backing_, loopBudgetBytes());
  }
  size_t loopBudgetBytes() const { return budgetBytes() / 4; }
  /// Brings every block out of memory back (for outputs that need the
  /// whole map: the final mesh, --save-map); the budget is exceeded after.
  void restoreEvicted();
  MemoryCounters memoryCounters() const { return memory_counters_; }

  /// Runs the whole pipeline on a few synthetic frames (a textured wall)
  /// into a scratch map, leaving this frontend untouched: first-use costs
  /// (library initialization, thread pools, allocator growth, page faults)
  /// are paid here instead of on the first live frames. DESIGN: without it
  /// the first three frames of a 30 FPS run took 40-90 ms (preprocess alone
  /// 38 ms) and missed their deadlines. Call before frames start arriving.
  void warmUp();

  /// Preprocess, track against the model, integrate, raycast the new model.
  /// A frame that cannot be tracked is reported and not fused; the map is
  /// unchanged and tracking resumes from the last good pose.
  /// `T_given` (evaluation: --fuse-ground-truth) replaces tracking: the
  /// frame is fused at that pose.
  FrameResult process(const RgbdFrame& frame, const Eigen::Isometry3d* T_given = nullptr);

  /// Between frames: fuse a correction computed on a snapshot of the map
  /// (the frontend stays the map's only writer).
  alg::PatchStats applyPatch(const alg::TsdfPatch& patch);

  /// The keyframes made since the last call, for the pose-feedback window
  /// (their images at feedback.image_level, tracking's relative motion and
  /// its information). Empty when feedback is disabled.
  std::vector<alg::WindowKeyframe> takeFeedbackKeyframes();
  /// Between frames: the keyframe's pose becomes `c.T_world_cam` in the
  /// trajectory; when it is the newest keyframe the live pose moves with it
  /// (the next frame is tracked from there). Other frames keep their poses:
  /// each was tracked against the map, not chained to the keyframe. A keyframe that moved beyond the feedback
  /// thresholds is queued for re-integration (reintegratePending). False for a keyframe no longer kept (slid out of the
  /// window).
  bool applyKeyframeCorrection(const KeyframeCorrection& c);
  /// Re-integrates up to `max` queued keyframes (de-integrated at the pose
  /// they were fused with, integrated at the corrected one); the count done.
  int reintegratePending(int max = 1 << 30);
  size_t reintegrationsPending() const { return reintegrate_queue_.size(); }
  FeedbackCounters feedbackCounters() const {
    FeedbackCounters c = feedback_counters_;
    c.reintegrations_pending = reintegrate_queue_.size();
    return c;
  }
  /// A copy of the map's blocks around the keyframes kept for pose
  /// feedback, for a solver on another thread (the map has one writer, the
  /// frontend; readers work on copies). Between frames, on the frontend's
  /// thread; timed in feedbackCounters().
  std::shared_ptr<const alg::TsdfMap> feedbackSnapshot();
  /// A copy the solver is done with (handed back through a ring, so its
  /// reads happened before): its memory makes the next copy.
  void reuseFeedbackSnapshot(const alg::TsdfMap* done);

  /// The ROI refinement jobs made since the last call (paper 3.3).
  std::vector<RefineJob> takeRefineJobs();
  /// At most this many jobs from the next keyframes (negative: only
  /// max_jobs_per_keyframe bounds them, the default). The real-time runner
  /// sets it to the number of idle workers before each frame.
  void setRefineBudget(int jobs) { refine_budget_ = jobs; }
  /// Between frames: fuse a job's write-back and hand its sigma_Neural to
  /// the quality map. Returns the patch statistics.
  alg::PatchStats applyRefinement(const RefineOutcome& outcome);
  /// The refined regions' fields for the pose feedback's implicit channels
  /// (the newest kMaxImplicitSurfaces; a field replaces older ones whose
  /// box center it contains). Safe from any thread.
  std::vector<std::shared_ptr<const alg::ImplicitSurface>> implicitSurfaces() const;
  static constexpr size_t kMaxImplicitSurfaces = 32;
  /// The refined regions' sub-voxel detail, oldest first (a detail drops
  /// older ones its box contains; the oldest go beyond kMaxDetailBytes).
  std::vector<std::shared_ptr<const alg::RefinedDetail>> details() const;
  static constexpr size_t kMaxDetailBytes = size_t{128} << 20;
  /// The map's mesh with the refined regions' detail (the TSDF's own mesh
  /// where nothing was refined). Call between frames, as for map().
  alg::TriangleMesh mesh(const alg::MeshParams& params) const;
  size_t refineJobsMade() const { return jobs_made_; }
  size_t refineJobsDropped() const { return jobs_dropped_; }

  const alg::TsdfMap& map() const { return map_; }
  /// The map at this instant for another thread, its voxel memory shared
  /// until the frontend next writes into it (TsdfMap::snapshot). Between
  /// frames.
  alg::TsdfMap mapSnapshot() { return map_.snapshot(); }
  const alg::PinholeCamera& camera() const { return camera_; }
  const FrontendParams& params() const { return params_; }
  /// Every processed frame's pose (lost frames carry the last good pose
  /// until tracking is back, then poses interpolated in time).
  const Trajectory& trajectory() const { return trajectory_; }
  size_t lostFrames() const { return lost_frames_; }
  const alg::TrackingCounts& trackingCounts() const { return state_machine_.counts(); }
  TrackingCounters trackingCounters() const {
    TrackingCounters c = tracking_counters_;
    c.database_keyframes = keyframe_db_.size();
    c.database_bytes = keyframe_db_.bytes();
    return c;
  }
  const alg::KeyframeDatabase& keyframeDatabase() const { return keyframe_db_; }
  /// The loop closer's counters with the frontend's part (odometry
  /// checks, corrections applied, stale refinements).
  LoopClosureCounters loopClosureCounters() const;
  /// Null when loop closure is off, or while detached.
  const LoopCloser* loopCloser() const { return loop_closer_.get(); }
  /// Real time: the loop closer moves to a thread of its own; process()
  /// then queues each keyframe for it (takeLoopKeyframes) instead of
  /// running it, and its corrections come back through
  /// applyLoopCorrection. Attached again once that thread has ended.
  std::unique_ptr<LoopCloser> detachLoopCloser() { return std::move(loop_closer_); }
  void attachLoopCloser(std::unique_ptr<LoopCloser> closer) { loop_closer_ = std::move(closer); }
  std::vector<LoopKeyframe> takeLoopKeyframes() { return std::exchange(loop_out_, {}); }
  /// Real time: a keyframe's ORB features are made on another thread
  /// (describeKeyframe): each keyframe goes out through takeLoopKeyframes
  /// with loop closure off too, and its features come back through
  /// addKeyframeFeatures. Relocalization matches against them from then.
  void describeKeyframesElsewhere(bool on) { describe_elsewhere_ = on; }
  /// A keyframe's features made elsewhere, into the keyframe database at
  /// the keyframe's pose as it is now (corrections applied since it was
  /// made included).
  void addKeyframeFeatures(const KeyframeFeatures& features);
  /// A loop closure's correction, between frames: every frame moves with
  /// its keyframe, later frames and the live pose with the newest; the
  /// correction's map replaces the map (refinement state and the quality
  /// map start over: they describe the old map's blocks).
  void applyLoopCorrection(LoopCorrection& correction);
  size_t keyframes() const { return keyframes_; }

  /// Quality of the map's regions (paper 3.2), updated on each keyframe.
  const alg::QualityMap& quality() const { return quality_; }
  /// Block scores and ROIs as of the last keyframe.
  const std::vector<alg::BlockScore>& blockScores() const { return scores_; }
  const std::vector<alg::Roi>& rois() const { return rois_; }
  /// The last fused frame and its pose (the last keyframe right after a
  /// keyframe), e.g. to draw the indicators over it.
  const alg::PreprocessedFrame& lastFrame() const { return last_frame_; }
  const Eigen::Isometry3d& lastPose() const { return T_last_; }

 private:
  /// Raycasts model_ at `T_world_cam`, with `frame`'s depth (the frame
  /// just tracked there) as the hint.
  void renderModel(const alg::PreprocessedFrame& frame, const Eigen::Isometry3d& T_world_cam);
  int minValidPixels() const;
  /// tracking.photometric_scale_m, or the median point-to-plane over
  /// photometric residual spread of the last fused frames.
  double photometricScale() const;
  void fillLostPoses(int64_t stamp_ns, const Eigen::Isometry3d& T_found);
  /// A frame got pose T (fused or only followed): the next frame is
  /// tracked from it.
  void followPose(const Eigen::Isometry3d& T_world_cam, const alg::PreprocessedFrame& pre);
  /// The frame's color camera relative to its depth camera: the motion
  /// over the time between the two images at the last velocity.
  Eigen::Isometry3d colorOffset(const alg::PreprocessedFrame& frame) const;
  /// Lost: the frame matched against the keyframe database; a PnP pose is
  /// taken only when ICP against the model rendered there confirms it
  /// within the noise gates and close to it. On success model_ is the
  /// model at the verified pose.
  bool relocalize(const alg::PreprocessedFrame& pre, const alg::TrackingParams& gates, alg::IcpResult& verified,
                  std::string& why);
  /// The keyframe's ORB features, added to the database (empty without color).
  alg::FrameFeatures addToKeyframeDatabase(uint32_t id, const alg::PreprocessedFrame& frame,
                                           const Eigen::Isometry3d& T_world_cam);
  /// The keyframe (last_frame_ at T_world_kf) for the loop closer: run
  /// at once offline (a correction is applied before process() returns),
  /// queued in real time (with loop closure off, only to be described).
  void sendToLoopCloser(uint32_t id, alg::FrameFeatures features, const alg::PreprocessedFrame& previous_kf,
                        const Eigen::Isometry3d& T_previous_kf, const Eigen::Isometry3d& T_previous_kf_color,
                        const Eigen::Isometry3d& T_world_kf);
  // The steps of process(), in order.
  /// Before the map has started: true when `pre` has the depth to start
  /// it; else the frame is counted lost at the initial pose.
  bool canStartMap(const alg::PreprocessedFrame& pre, FrameResult& r);
  /// Step 2: the pose (given, the first, or tracked) and its decision,
  /// with the tracking fields of `r` filled in.
  alg::TrackingDecision locate(const alg::PreprocessedFrame& pre, const Eigen::Isometry3d* T_given,
                               alg::IcpResult& icp, Eigen::Isometry3d& T_world_cam, FrameResult& r);
  /// Tracking lost: the map and the last pose are kept, motion restarts from rest.
  void keepLost(FrameResult& r);
  /// Tracked but not to be fused: the camera is followed.
  void followWithoutFusing(const alg::PreprocessedFrame& pre, const Eigen::Isometry3d& T_world_cam,
                           const alg::TrackingDecision& decision, FrameResult& r);
  /// Step 3: the frame fused at its pose; it becomes the last frame.
  void fuse(alg::PreprocessedFrame& pre, const Eigen::Isometry3d& T_world_cam, FrameResult& r);
  /// Step 5: the frame (last_frame_) becomes a keyframe: quality and
  /// refinement jobs, the feedback window, the keyframe database, loop closure.
  void makeKeyframe(const alg::IcpResult& icp, const Eigen::Isometry3d& T_world_kf, FrameResult& r);
  /// Within locate(): the decision, the result that gave the pose (or the
  /// model's failed one) and the pose.
  alg::TrackingDecision track(const alg::PreprocessedFrame& pre, alg::IcpResult& icp, Eigen::Isometry3d& T_world_cam);
  void scoreKeyframe(FrameResult& r);
  void keepKeyframeImages(uint32_t id);
  void makeRefineJobs(uint32_t keyframe_id);
  void keepFeedbackKeyframe(uint32_t id, int64_t stamp_ns, const alg::IcpResult* icp,
                            const Eigen::Isometry3d& T_previous_kf);

  /// Resuming: counts the frames until one relocalizes, and gives up.
  void checkResume(const FrameResult& r);
  /// Memory budget: blocks in the view predicted for the next frame come
  /// back (up to the per-frame cap), nearest first.
  void prefetch(const Eigen::Isometry3d& T_world_predicted);
  /// Memory budget: past it, the blocks farthest from the camera leave.
  void enforceBudget(const Eigen::Isometry3d& T_world_cam);
  size_t budgetBytes() const;
  /// Blocks held elsewhere (packed keys) back into the map, counted.
  void bringBack(const std::vector<uint64_t>& keys);
  /// Adds the blocks the map took back since the last count (prefetch, fusion).
  void countTakenBack();
  void makeLoopCloser();

  alg::PinholeCamera camera_;
  FrontendParams params_;
  ParallelFor parallel_;
  alg::TsdfMap map_;
  std::vector<alg::ModelView> model_;  ///< model pyramid rendered at T_last_
  alg::PreprocessedFrame last_frame_;  ///< the last fused frame
  /// The last frame with a pose (fused or only followed): the photometric
  /// reference and the frame-to-frame fallback's model.
  alg::PreprocessedFrame previous_frame_;
  Eigen::Isometry3d T_previous_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_previous_color_ = Eigen::Isometry3d::Identity();  ///< its color image's pose
  alg::PreprocessedFrame keyframe_reference_;  ///< the last keyframe (photometric reference when so configured)
  Eigen::Isometry3d T_keyframe_color_ = Eigen::Isometry3d::Identity();
  int64_t previous_depth_ns_ = 0;
  double velocity_dt_s_ = 0;     ///< the time velocity_ spans (0: unknown)
  bool velocity_valid_ = false;  ///< the last frame had a pose
  alg::TrackingStateMachine state_machine_;
  TrackingCounters tracking_counters_;
  /// Point-to-plane over photometric residual spread of the last fused
  /// frames (tracking.photometric_scale_from_residuals).
  std::deque<double> photometric_ratios_;
  alg::KeyframeDatabase keyframe_db_;
  std::optional<size_t> lost_since_;  ///< trajectory index of the first frame of the current loss
  bool initialized_ = false;
  alg::BlockBacking* backing_ = nullptr;
  alg::BlockBacking* loop_backing_ = nullptr;
  MemoryCounters memory_counters_;
  uint64_t taken_back_seen_ = 0;  ///< map_.blocksTakenBack() when last counted
  bool resuming_ = false, resume_abandoned_ = false;
  std::atomic<bool> resume_failed_{false};
  int64_t resumed_at_frame_ = -1;
  int64_t frames_seen_ = 0;
  uint32_t keyframe_id_base_ = 0;  ///< ids below are the saved map's keyframes
  Eigen::Isometry3d T_initial_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_last_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d velocity_ = Eigen::Isometry3d::Identity();  ///< T_prev^-1 T_last
  Eigen::Isometry3d T_last_kf_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_world_odom_ = Eigen::Isometry3d::Identity();  ///< loop closures' corrections, composed
  int64_t last_kf_ns_ = 0;
  float last_kf_depth_m_ = 0;  ///< median depth of the last keyframe (its coarsest level)
  Trajectory trajectory_;
  size_t lost_frames_ = 0, keyframes_ = 0;
  alg::QualityMap quality_;
  std::vector<alg::BlockScore> scores_;
  std::vector<alg::Roi> rois_;
  std::deque<alg::KeyframeImages> keyframe_images_;  ///< newest last
  std::vector<RefineJob> pending_jobs_;
  std::unordered_map<uint64_t, uint32_t> block_submitted_;  ///< block -> keyframe id of its last job
  uint64_t next_job_id_ = 1;
  size_t jobs_made_ = 0, jobs_dropped_ = 0;
  // Pose feedback: the keyframes whose poses may still be corrected, with
  // what was fused for each (shared buffers), to re-integrate them.
  struct KeptKeyframe {
    uint32_t id = 0;
    size_t trajectory_index = 0;
    Eigen::Isometry3d T_fused = Eigen::Isometry3d::Identity();  ///< the pose its observation is in the map at
    alg::DepthObservation observation;
    Eigen::AlignedBox3f box_world;  ///< what it sees, widened by the truncation band
  };
  std::deque<KeptKeyframe> kept_;  ///< newest last
  /// Map copies made for the feedback thread (a few, reused once given back).
  struct SnapshotSlot {
    std::shared_ptr<alg::TsdfMap> map;
    bool in_use = false;
  };
  std::vector<SnapshotSlot> snapshot_slots_;
  std::vector<alg::WindowKeyframe> feedback_out_;
  std::deque<uint32_t> reintegrate_queue_;
  FeedbackCounters feedback_counters_;
  // Loop closure: the closer (detached in real time), each keyframe's
  // trajectory entry (with relocalization on), keyframes queued for the
  // closer's thread (or only to be described), the
  // corrections applied, and the frontend's own counts.
  std::unique_ptr<LoopCloser> loop_closer_;
  std::map<uint32_t, size_t> keyframe_index_;
  std::vector<LoopKeyframe> loop_out_;
  bool describe_elsewhere_ = false;
  uint64_t loop_epoch_ = 0;
  LoopClosureCounters loop_counters_;
  uint64_t map_epoch_ = 0;
  mutable std::mutex surfaces_mutex_;
  std::deque<std::shared_ptr<const alg::FieldSurface>> surfaces_;  ///< newest first
  std::deque<std::shared_ptr<const alg::RefinedDetail>> details_;  ///< oldest first (under surfaces_mutex_)
  size_t detail_bytes_ = 0;
  int refine_budget_ = -1;
};

}  // namespace hxmap::rt
