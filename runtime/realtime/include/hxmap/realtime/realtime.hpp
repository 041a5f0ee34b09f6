// Real-time playback through the runtime's threads: frames are published at
// their recorded rate (or a given one) by a sensor thread, the frontend
// thread processes the newest within the frame deadline, a refinement worker
// pool runs background jobs in cooperative slices admitted by the scheduler,
// and a pose-feedback thread consumes keyframes.
//
// Frames come from a FrameSource: a recording played at its recorded rate
// (PlaybackSource) or a live camera (runtime/camera), whose next() blocks
// until the device delivers.
//
// The run is a chain of stages, each a named thread that owns its input
// ring (runtime/realtime/src/stages.hpp), created and joined by runRealtime:
//   hx-sensor     pulls frames from the source and publishes each into the
//                 frontend's inbox (the newest frame only: an unread older
//                 frame is replaced and counted as dropped).
//   hx-frontend   the only thread touching the Frontend (and so the map);
//                 hands ROI jobs to the refinement workers and keyframes to
//                 pose feedback and loop closure.
//   hx-refine-N   refinement workers: the frontend's ROI jobs (paper 3.3),
//                 each slice (field setup, a few training iterations, the
//                 write-back) admitted by the scheduler first.
//   hx-feedback   pose feedback (paper 3.4): keyframes join the sliding
//                 window, solved in scheduler-admitted slices on a copy of
//                 the map around the window made by the frontend's thread.
//   hx-loop       loop closure, when configured: the loop closer's steps in
//                 scheduler-admitted slices.
// Results flow back to the frontend through rings too (TSDF patches from
// each worker, keyframe corrections from feedback, loop corrections with
// their rebuilt maps) and are applied between frames, so the frontend
// stays the map's only writer; keyframes that moved are re-integrated
// after a frame when the slack allows.
// The calling thread prints the status line and watches `stop` (set by a
// signal handler): on stop the sensor stops publishing, the frontend finishes
// the frame in hand, workers cancel their jobs, and everything is joined, so
// the caller can write every output.
#pragma once

#include <algorithm>

#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "hxmap/core/expected.hpp"
#include "hxmap/core/frame.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/scheduler/scheduler.hpp"
#include "hxmap/scheduler/trace.hpp"

namespace hxmap::rt {

/// Where the sensor thread gets frames. next() is called on hx-sensor only.
class FrameSource {
 public:
  virtual ~FrameSource() = default;
  /// The next frame, returned when it is due (a recording) or delivered (a
  /// camera); nothing at the end of the stream or once `stop` is set; an
  /// Error when the source failed for good (the run ends, what was mapped
  /// is kept).
  virtual Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) = 0;
  /// The frame rate the scheduler plans for.
  virtual double fps() const = 0;
  /// Frames the source will deliver, 0 when unknown (a live camera).
  virtual size_t size() const { return 0; }
  /// A line on what the source counted (drops, gaps), for the run report.
  virtual std::string statsText() const { return {}; }
};

/// Frames already in memory, each released at its recorded stamp (or at
/// `fps` when > 0) counted from the first call to next().
class PlaybackSource : public FrameSource {
 public:
  PlaybackSource(const std::vector<RgbdFrame>& frames, double fps);
  Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) override;
  double fps() const override { return fps_; }
  size_t size() const override { return frames_.size(); }

 private:
  const std::vector<RgbdFrame>& frames_;
  std::vector<int64_t> due_ns_;
  double fps_ = 30;
  size_t next_ = 0;
  int64_t t0_ns_ = 0;
};

/// Frames already in memory, each handed over as soon as it is asked for
/// (a serial run's input in tests and benchmarks).
class FrameList : public FrameSource {
 public:
  explicit FrameList(const std::vector<RgbdFrame>& frames) : frames_(frames) {}
  Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) override {
    if (next_ >= frames_.size() || stop.load()) return std::optional<RgbdFrame>{};
    return std::optional<RgbdFrame>{frames_[next_++]};  // cv::Mat copies share the pixels
  }
  double fps() const override { return 30; }
  size_t size() const override { return frames_.size(); }

 private:
  const std::vector<RgbdFrame>& frames_;
  size_t next_ = 0;
};

/// At most `max_frames` frames of another source (0: all of them), then the
/// end of the stream: `hxmap run --max-frames` on a live camera.
class FrameLimit : public FrameSource {
 public:
  FrameLimit(FrameSource& inner, size_t max_frames) : inner_(inner), max_(max_frames) {}
  Expected<std::optional<RgbdFrame>> next(const std::atomic<bool>& stop) override {
    if (max_ > 0 && delivered_ >= max_) return std::optional<RgbdFrame>{};
    auto f = inner_.next(stop);
    if (f && *f) ++delivered_;
    return f;
  }
  double fps() const override { return inner_.fps(); }
  size_t size() const override {
    const size_t n = inner_.size();
    return max_ == 0 ? n : n == 0 ? max_ : std::min(n, max_);
  }
  std::string statsText() const override { return inner_.statsText(); }

 private:
  FrameSource& inner_;
  size_t max_ = 0;
  size_t delivered_ = 0;
};

/// What a checkpoint of a live run writes: a snapshot of the map (its
/// voxel memory shared with the live map until the frontend writes into
/// it, see TsdfMap::snapshot), its refined details and the trajectory so
/// far (read on any thread).
struct MapCheckpoint {
  std::shared_ptr<const alg::TsdfMap> map;
  std::vector<std::shared_ptr<const alg::RefinedDetail>> details;
  Trajectory trajectory;
};

/// Work of its own beside the stages, on threads it starts, under the run's
/// scheduler (benchmarks and tests: a CPU burner to watch the scheduler
/// shed work). Started after the stages; when the run ends `stopping` is
/// set and the scheduler's waiters are woken, then join() is called.
class BackgroundLoad {
 public:
  virtual ~BackgroundLoad() = default;
  /// `now_ns`: the run's clock; `trace`: null or the run's trace.
  virtual void start(Scheduler& sched, std::function<int64_t()> now_ns, const std::atomic<bool>& stopping,
                     TraceRecorder* trace) = 0;
  virtual void join() = 0;
  /// A line for the run report.
  virtual std::string reportLine() const = 0;
};

struct RealtimeOptions {
  double fps = 0;             ///< playback rate of a frame vector; 0 = the recorded stamps
  SchedulerParams scheduler;  ///< target_fps is set from the source's rate
  int refine_workers = 1;
  /// Nice value the refinement workers and the pose-feedback thread take
  /// (Linux: per thread; 0 = unchanged). DESIGN: the scheduler admits
  /// background slices only into predicted slack, but a slice already
  /// running when a frame arrives competes with the frontend for the
  /// cores; niced, the kernel hands the frontend the core first. A
  /// safeguard: on the TUM slice at 30 FPS nice 10 and 0 measured the same
  /// misses (the misses then were the cold start, see Frontend::warmUp).
  /// Under other load (other processes at nice 0) niced workers may starve.
  int background_nice = 10;
  /// How the loop-closure thread runs its data-parallel loops; null =
  /// serially. Its own pool (not the frontend's): its slices run in
  /// predicted slack, when the frontend leaves the cores idle.
  ParallelFor loop_parallel;
  /// Run Frontend::warmUp on the frontend thread before the sensor thread
  /// reads the first frame.
  bool warm_up = true;
  /// Extra background work under the scheduler (not owned; null: none).
  BackgroundLoad* extra_load = nullptr;
  double status_interval_s = 0.5;  ///< status line period; 0 = none
  /// Called on hx-frontend after each frame, between frames (e.g. to
  /// publish the pose and map): it may read the frontend, and its time is
  /// taken from the slack before the next frame.
  std::function<void(const FrameResult&, const Frontend&, const RunCounters&)> on_frame;
  /// Every checkpoint_s (0: never) the frontend thread takes a snapshot of
  /// the map in the slack after a frame (forced when two intervals overdue)
  /// and hands it to on_checkpoint, which must not block (the snapshot is
  /// meshed and written on another thread).
  double checkpoint_s = 0;
  std::function<void(MapCheckpoint&&)> on_checkpoint;
  /// Called on hx-frontend for each refinement outcome it applies.
  std::function<void(const RefineOutcome&)> on_refined;
  /// A pose to fuse a frame at instead of tracking it (true: `T_world_cam`
  /// set), e.g. the ground truth; null: every frame is tracked.
  std::function<bool(const RgbdFrame&, Eigen::Isometry3d& T_world_cam)> given_pose;
  /// Checked before each frame of a serial run: true ends it as `stop` does.
  std::function<bool()> should_stop;
};

struct RealtimeStats {
  SchedulerCounters counters;
  double wall_s = 0;
  double fps = 0;                                 ///< frames processed per second of playback
  double latency_p50_ms = 0, latency_p99_ms = 0;  ///< arrival to pose
  double frontend_p50_ms = 0, frontend_p99_ms = 0;
  uint64_t keyframes_to_feedback = 0, feedback_ring_full = 0;
  uint64_t patches_applied = 0, corrections_applied = 0;  ///< results applied between frames
  /// Pose feedback: windows solved, skipped (effort 0), cut short (shed);
  /// keyframe corrections sent to the frontend.
  uint64_t feedback_windows_solved = 0, feedback_windows_skipped = 0, feedback_windows_shed = 0;
  uint64_t feedback_corrections_sent = 0;
  /// ROI refinement jobs: handed to workers, rejected (every worker's ring
  /// full), completed and written back, shed by the scheduler.
  uint64_t refine_jobs_submitted = 0, refine_jobs_rejected = 0, refine_jobs_completed = 0, refine_jobs_shed = 0;
  uint64_t refine_outcomes_dropped = 0, refine_slices = 0, refine_voxels_written = 0;
  /// Map snapshots for checkpoints (how many were forced without the
  /// slack), what each cost the frontend thread, and the chunks of blocks
  /// the frontend copied afterwards before writing into them.
  uint64_t checkpoints = 0, checkpoints_forced = 0;
  double checkpoint_copy_p50_ms = 0, checkpoint_copy_max_ms = 0;
  uint64_t checkpoint_chunks_copied = 0;
  bool stopped_early = false;
  std::string source_error;  ///< why the source ended early (empty: it ran out or was stopped)
  std::string report;        ///< the final table
  FeedbackTally feedback;    ///< pose feedback's solves (empty when off)
  std::vector<FrameResult> results;
};

/// Records a processed frame's stages in `trace`. They run back to back
/// inside Frontend::process, so they are laid out from its start.
void traceFrameStages(TraceRecorder& trace, const FrameResult& result, int64_t start_ns, int thread, int64_t frame);

/// Runs the frames of `source` through the threads until it ends, fails or
/// `stop` is set. `heartbeat` (optional) is called by the calling thread
/// about every status interval while the run is healthy (service watchdog).
RealtimeStats runRealtime(FrameSource& source, Frontend& frontend, const RealtimeOptions& options,
                          const std::atomic<bool>& stop, TraceRecorder* trace = nullptr,
                          const std::function<void()>& heartbeat = {});

/// The same stages as runRealtime, one after another on the calling thread:
/// each frame is read when the previous one and all the work it made
/// (refinement jobs to their iteration cap, the pose-feedback window, loop
/// closure's steps) are done and applied. No wall-clock budget and no
/// scheduler verdict: the same input gives the same outputs on any machine
/// under any load (offline runs). Ends when the source does, fails, `stop`
/// is set or options.should_stop says so; the fps, warm-up, status line
/// and background_nice options do not apply.
RealtimeStats runSerial(FrameSource& source, Frontend& frontend, const RealtimeOptions& options,
                        const std::atomic<bool>& stop, TraceRecorder* trace = nullptr);

/// Plays `frames` (already loaded; stamps give the recorded rate, or
/// options.fps) through the threads.
RealtimeStats runRealtime(const std::vector<RgbdFrame>& frames, Frontend& frontend, const RealtimeOptions& options,
                          const std::atomic<bool>& stop, TraceRecorder* trace = nullptr,
                          const std::function<void()>& heartbeat = {});

}  // namespace hxmap::rt
