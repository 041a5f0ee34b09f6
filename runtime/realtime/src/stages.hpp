// The real-time runner's stages (internal to runRealtime). Each stage owns
// its thread and its input ring, knows the stage its output goes to, and
// is started and joined by runRealtime, which reads as the data flow:
//
//   source -> SensorStage -> FrameInbox -> FrontendStage -+-> RefinePool (ROI jobs) --+
//                                            ^            +-> FeedbackStage (keyframes)+-> results back
//                                            |            +-> LoopStage (keyframes) ---+   to the frontend,
//                                            +-------------------------------------------  applied between frames
//
// The frontend stage is the only one touching the Frontend (and so the
// map) while the threads run; background stages read their own copies.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "hxmap/frontend/frontend.hpp"
#include "hxmap/realtime/realtime.hpp"
#include "hxmap/ring/doorbell.hpp"
#include "hxmap/ring/spsc_ring.hpp"
#include "hxmap/scheduler/scheduler.hpp"
#include "hxmap/scheduler/trace.hpp"

namespace hxmap::rt::stages {

using Clock = std::chrono::steady_clock;

/// What every stage of one run shares: the scheduler, the trace, the run's
/// clock, and the flag that ends the background stages.
///
/// A serial run (runSerial) calls the same stages one after another on one
/// thread: every background slice is admitted at once, the slack is
/// unbounded, and no stage waits (the outputs do not depend on the machine).
struct RunContext {
  RunContext(const SchedulerParams& params, TraceRecorder* trace_, bool serial_ = false)
      : sched(params), trace(trace_), t0(Clock::now()), serial(serial_) {}
  int64_t nowNs() const { return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - t0).count(); }
  /// The scheduler's verdict on a background slice (serial: run it).
  Verdict admit(JobTicket& ticket) { return serial ? Verdict::kRun : sched.admitSlice(ticket, nowNs()); }
  /// Predicted slack before the next frame (serial: unbounded).
  double slackMs() const { return serial ? std::numeric_limits<double>::infinity() : sched.slackMs(nowNs()); }
  /// Sleeps until a frame ends after `epoch` was read, unless the
  /// background stages are stopping (read `epoch` first, as for a Doorbell).
  void waitForFrameEnd(uint64_t epoch) const {
    if (!stopping.load()) sched.waitForFrameEnd(epoch);
  }
  /// Ends the background stages: set first, then every doorbell is rung.
  void stopBackground() {
    stopping.store(true);
    sched.wakeAll();
  }

  Scheduler sched;
  TraceRecorder* trace;
  Clock::time_point t0;
  const bool serial;
  std::atomic<bool> stopping{false};
};

/// A frame with its arrival time and its index in the run (moved through
/// the inbox; the images are shared, never copied).
struct Arrival {
  RgbdFrame frame;
  int64_t arrival_ns = 0;
  int64_t index = 0;
};

/// The frontend's input: the newest frame only (an unread one is replaced).
using FrameInbox = LatestInbox<Arrival>;

/// hx-sensor: pulls frames from the source into the frontend's inbox.
class SensorStage {
 public:
  SensorStage(RunContext& ctx, FrameSource& source, FrameInbox& out) : ctx_(ctx), source_(source), out_(out) {}
  /// Starts reading once `go` is set (the frontend has warmed up).
  void start(const std::atomic<bool>& stop, const std::atomic<bool>& go);
  void join() { thread_.join(); }
  /// The next frame from the source, stamped with its arrival; nothing at
  /// the end of the stream, once `stop` is set, or when the source failed
  /// (`error`). The sensor thread, or the serial run's loop.
  std::optional<Arrival> pull(const std::atomic<bool>& stop);

  // Read after join.
  int64_t first_arrival_ns = 0, last_arrival_ns = 0;
  std::string error;  ///< why the source failed (empty: it ran out or was stopped)

 private:
  void run(const std::atomic<bool>& stop);

  int64_t pulled_ = 0;

  RunContext& ctx_;
  FrameSource& source_;
  FrameInbox& out_;
  std::thread thread_;
};

/// Counters the refinement workers share.
struct RefineCounters {
  std::atomic<uint64_t> slices{0}, done{0}, shed{0}, outcomes_full{0};
  /// Jobs delivered without their field sampled for feedback (that slice shed).
  std::atomic<uint64_t> surfaces_shed{0};
};

/// hx-refine-N: ROI jobs (paper 3.3) in scheduler-admitted slices (the
/// field's setup, a few training iterations at a time, the write-back);
/// outcomes go back to the frontend. Shed or stopped, a job is dropped and
/// the map keeps its fused values.
class RefineWorker {
 public:
  RefineWorker(RunContext& ctx, int index, const alg::ImplicitParams& params, int nice, RefineCounters& counters)
      : ctx_(ctx), index_(index), params_(params), nice_(nice), counters_(counters) {}
  void start() {
    thread_ = std::thread([this] { run(); });
  }
  void join() {
    bell_.ring();
    thread_.join();
  }
  bool idle() const { return in_flight_.load() == 0; }
  /// Frontend thread: false when the worker's ring is full.
  bool offer(RefineJob&& job);
  /// Frontend thread (the calling thread after join).
  bool takeOutcome(RefineOutcome& out) { return outcomes_.tryPop(out); }
  /// Runs the queued jobs (the worker's thread, or a serial run's loop).
  void runQueued();

 private:
  void run();
  void runJob(RefineJob& job);

  RunContext& ctx_;
  int index_;
  alg::ImplicitParams params_;
  int nice_;
  RefineCounters& counters_;
  SpscRing<RefineJob> jobs_{4};
  SpscRing<RefineOutcome> outcomes_{8};
  std::atomic<int> in_flight_{0};  ///< queued or running
  Doorbell bell_;
  std::thread thread_;
};

/// The refinement workers; jobs go to them in turn.
class RefinePool {
 public:
  RefinePool(RunContext& ctx, int workers, const alg::ImplicitParams& params, int nice);
  size_t size() const { return workers_.size(); }
  void start();
  void join();
  /// Frontend thread: workers with nothing queued or running.
  int idleWorkers() const;
  /// Frontend thread: each job to the next worker with room, or rejected
  /// (every ring full) and counted. A serial run makes room by running
  /// the worker's queue first.
  void submit(std::vector<RefineJob> jobs);
  /// A serial run: every worker's queued jobs, to their end.
  void runQueued() {
    for (auto& w : workers_) w->runQueued();
  }
  /// Frontend thread (the calling thread after join): finished outcomes.
  template <typename Apply>
  void drainOutcomes(Apply&& apply) {
    for (auto& w : workers_) {
      for (RefineOutcome outcome; w->takeOutcome(outcome);) apply(outcome);
    }
  }

  RefineCounters counters;
  uint64_t submitted = 0, rejected = 0;  ///< frontend thread

 private:
  RunContext& ctx_;
  std::vector<std::unique_ptr<RefineWorker>> workers_;
  size_t next_ = 0;  ///< frontend thread
};

/// hx-feedback: pose feedback (paper 3.4). New keyframes join the sliding
/// window, then the window is solved in scheduler-admitted slices on the
/// map copy that came with the newest keyframe, with as many iterations as
/// the scheduler's effort level allows (0: the window waits for the next
/// keyframe). Corrections go back to the frontend.
class FeedbackStage {
 public:
  FeedbackStage(RunContext& ctx, const Frontend& frontend, int max_effort, int nice, int lane);
  void start() {
    thread_ = std::thread([this] { run(); });
  }
  void join() {
    bell_.ring();
    thread_.join();
  }
  /// Frontend thread: keyframes waiting for a map copy, handed over with
  /// one when the frame left the slack for it (a keyframe's own frame
  /// seldom has it).
  void offer(std::vector<alg::WindowKeyframe> keyframes, Frontend& frontend);
  /// Frontend thread (the calling thread after join).
  bool takeCorrection(KeyframeCorrection& out) { return corrections_.tryPop(out); }
  /// New keyframes into the window, then the window solved once; false
  /// when no keyframe came (the feedback thread, or a serial run's loop).
  bool solveQueued();
  /// The solver's tally, once the thread is joined or the serial run ends.
  const FeedbackTally& tally() const { return solver_.tally(); }

  std::atomic<uint64_t> keyframes_seen{0}, windows_skipped{0}, windows_shed{0}, corrections_full{0};
  uint64_t keyframes_full = 0;  ///< frontend thread

 private:
  void run();

  RunContext& ctx_;
  const Frontend& frontend_;  ///< read only for its refined fields (implicitSurfaces is thread safe)
  alg::FeedbackParams params_;
  int max_effort_, nice_, lane_;
  FeedbackSolver solver_;  ///< feedback thread until joined
  std::shared_ptr<const alg::TsdfMap> snapshot_;  ///< the map copy the window is solved on
  SpscRing<FeedbackInput> keyframes_{16};
  SpscRing<KeyframeCorrection> corrections_{64};
  /// Map copies the solver is done with, back to the frontend's thread for
  /// reuse (the ring orders the solver's reads before the next copy's writes).
  SpscRing<std::shared_ptr<const alg::TsdfMap>> snapshots_done_{16};
  std::vector<alg::WindowKeyframe> backlog_;  ///< frontend thread: waiting for a map copy
  Doorbell bell_;
  std::thread thread_;
};

/// hx-loop: the loop closer's steps, each a scheduler-admitted slice.
/// Keyframes come in order and none may be lost (the graph needs every
/// one): those the ring has no room for wait on the frontend's side.
/// Corrections with their rebuilt maps go back to the frontend.
class LoopStage {
 public:
  /// Takes the frontend's loop closer (if any) and, with relocalization
  /// on, the making of its keyframes' ORB features.
  LoopStage(RunContext& ctx, Frontend& frontend, const ParallelFor& parallel, int nice, int lane);
  /// A loop closer came with the run (it stays so after finish).
  bool enabled() const { return enabled_; }
  /// Keyframes' features are made here (relocalization on).
  bool describing() const { return describe_; }
  void start();
  void join();
  /// Frontend thread.
  void offer(std::vector<LoopKeyframe> keyframes);
  /// Frontend thread.
  bool takeCorrection(LoopCorrection& out);
  /// Frontend thread: a keyframe's features for its database.
  bool takeFeatures(KeyframeFeatures& out);
  /// A serial run: the queued keyframes in, and every step they make.
  void stepQueued();
  /// The calling thread, after join: what was still queued or under way is
  /// finished (the graph holds every keyframe, the keyframe database every
  /// keyframe's features, and a last closure still corrects the trajectory
  /// written); the closer goes back to `frontend`.
  void finish(Frontend& frontend);

  std::atomic<uint64_t> slices{0}, forced{0}, waits{0};
  /// Milliseconds making keyframe features, each (loop thread until joined).
  std::vector<double> describe_ms;

 private:
  void run();
  /// A keyframe from the frontend: described if it has to be, then to the
  /// closer (with images of its own while the frontend runs on).
  void take(LoopKeyframe kf, bool own_images = true);
  void sendFeatures();
  /// The frontend's side of a ring from this stage: the next item, or in a
  /// serial run what the ring had no room for.
  template <typename T>
  bool takeSent(SpscRing<T>& ring, std::deque<T>& unsent, T& out);

  RunContext& ctx_;
  std::unique_ptr<LoopCloser> closer_;
  bool enabled_, describe_;
  alg::RelocalizationParams relocalization_;
  int nice_, lane_;
  SpscRing<LoopKeyframe> keyframes_{32};
  SpscRing<LoopCorrection> corrections_{4};
  SpscRing<KeyframeFeatures> features_{32};
  std::deque<LoopKeyframe> backlog_;   ///< frontend thread
  std::deque<LoopCorrection> unsent_;  ///< loop thread until joined: corrections the ring had no room for
  std::deque<KeyframeFeatures> unsent_features_;  ///< loop thread until joined
  Doorbell bell_;
  std::thread thread_;
};

/// hx-frontend: the only thread touching the Frontend. Between frames it
/// applies what the background stages sent back, and after each frame it
/// hands the frame's jobs and keyframes on.
class FrontendStage {
 public:
  FrontendStage(RunContext& ctx, Frontend& frontend, const RealtimeOptions& options, RefinePool& refine,
                FeedbackStage& feedback, LoopStage& loop);
  FrameInbox& inbox() { return inbox_; }
  /// Set once the frontend has warmed up (or at once without warm-up).
  const std::atomic<bool>& ready() const { return ready_; }
  void start() {
    thread_ = std::thread([this] { run(); });
  }
  void join() { thread_.join(); }
  bool done() const { return done_.load(); }
  uint64_t framesDone() const { return frames_done_.load(std::memory_order_relaxed); }
  /// Refinement outcomes into the map: the frontend thread between frames,
  /// the calling thread once the threads are joined.
  void applyOutcomes();
  /// One frame: what came back first, the frame, its work handed on, then
  /// re-integration and checkpoint into the slack (the frontend thread, or
  /// a serial run's loop).
  void step(const Arrival& a);
  /// A serial run, after the background stages ran: what they sent back
  /// and every re-integration it calls for, before the next frame.
  void settle();

  // Read after join.
  std::vector<double> latency_ms, frontend_ms;
  std::vector<FrameResult> results;
  std::vector<double> checkpoint_copy_ms;
  uint64_t checkpoints_forced = 0;
  /// Chunks of blocks the frontend copied before writing into them because
  /// a checkpoint's snapshot shared them (TsdfMap::snapshot).
  uint64_t chunks_copied_on_write = 0;
  uint64_t patches_applied = 0, voxels_written = 0, corrections_applied = 0, loop_applied = 0;
  double loop_apply_ms = 0;

 private:
  void run();
  void applyBackgroundResults();
  FrameResult process(const Arrival& a);
  void handOn();
  void reintegrateIntoSlack(const FrameResult& r);
  void checkpointIntoSlack();

  RunContext& ctx_;
  Frontend& frontend_;
  const RealtimeOptions& options_;
  RefinePool& refine_;
  FeedbackStage& feedback_;
  LoopStage& loop_;
  FrameInbox inbox_;
  std::atomic<bool> ready_{false}, done_{false};
  std::atomic<uint64_t> frames_done_{0};
  int64_t last_checkpoint_ns_ = -1;
  uint64_t map_chunks_copied_seen_ = 0;
  std::thread thread_;
};

/// Names the calling thread (shown by top -H, gdb, perf).
void nameThisThread(const char* name);
/// Lowers the calling thread's priority (Linux nice values are per thread).
/// Failure is logged, not fatal: the thread then runs at the process's.
void niceThisThread(const char* name, int nice);

}  // namespace hxmap::rt::stages
