// Deadline scheduler: keeps the frontend on its frame deadline and admits
// background work (ROI refinement slices, pose feedback) only into predicted
// slack.
//
// Model (DESIGN): on the target machine the frontend's data-parallel stages
// use every core, so background work competes with it for the same CPUs.
// Work is therefore admitted only when it is predicted to end before the next
// frame is due, a margin earlier: the predicted slack of the current period
// is (next arrival - margin) - max(now, predicted end of the frame in
// progress), and when a frame has arrived but not started, its predicted
// cost is added to that end. A job's slice is admitted when its predicted
// cost fits (and not before `warmup_frames` frames have measured costs); a job
// that found no slack for `shed_after_periods` periods is shed (never
// started: "not started"), a started one after `recent_frames` periods more
// ("cancelled"; see admitSlice); a started job that waits is "paused". Pose
// feedback degrades before it is shed: its effort level (0 = off ..
// max_feedback_effort) drops while the slack of recent frames cannot hold it
// and recovers when it can.
//
// Costs are learned per stage and per job kind: EWMA and the maximum of the
// recent frames; predictions use the larger. Percentiles come from a bounded
// window of recent samples.
//
// Threads: frameStarted/frameFinished are called by the frontend thread
// only; frameArrived/framesDropped by the frontend or the sensor thread (one
// of them); admitSlice/sliceFinished/jobFinished by
// background threads, each for its own JobTicket. The values they share
// (period end, predicted frame end, counters) are atomics. costs() and
// report() read frontend-owned models: call them from the frontend thread
// or after the threads have stopped. Time is given by the caller (steady
// clock in the runtime, a virtual clock in replay tests), so the scheduler
// never sleeps or reads a clock itself.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

namespace hxmap::rt {

struct SchedulerParams {
  double target_fps = 25.0;     ///< frame deadline = 1 / target_fps after arrival
  double margin_ms = 1.0;       ///< kept free before the next frame is due
  double ewma_alpha = 0.2;      ///< weight of the newest cost sample
  int recent_frames = 32;       ///< window of the recent maximum and percentiles (frames)
  int shed_after_periods = 8;   ///< a job without slack for this many periods is shed (started: + recent_frames)
  int max_feedback_effort = 3;  ///< pose feedback effort levels above 0 (off)
  int warmup_frames = 3;        ///< no background slice before this many frames have a measured cost
  int background_lanes = 0;     ///< background slices that may run at once (0: one per core)
};

/// Cost of one stage or job kind: EWMA, recent maximum, percentiles.
class CostModel {
 public:
  explicit CostModel(double alpha = 0.2, size_t window = 32) : alpha_(alpha), window_(window) {}
  void add(double ms);
  bool empty() const { return count_ == 0; }
  size_t count() const { return count_; }
  double ewma() const { return ewma_; }
  /// The EWMA becomes min(EWMA, ms) (a prediction that decayed with age).
  void lowerEwma(double ms);
  double recentMax() const;
  /// What the scheduler plans with: max(EWMA, recent maximum).
  double predict() const { return std::max(ewma_, recentMax()); }
  /// Percentile q in [0, 1] of the recent window (all samples when fewer).
  double percentile(double q) const;

 private:
  double alpha_;
  size_t window_;
  size_t count_ = 0;
  double ewma_ = 0.0;
  std::vector<double> recent_;  ///< ring of the last `window_` samples
  size_t next_ = 0;
};

/// Frontend stages the scheduler tracks (per-frame cost each).
enum class FrontendStage { kPreprocess, kTrack, kIntegrate, kRaycast, kTotal, kCount };
const char* frontendStageName(FrontendStage s);

/// One background job as the scheduler sees it; owned by the thread that
/// runs it.
struct JobTicket {
  std::string kind;              ///< e.g. "refine", "feedback": costs are learned per kind
  double slice_estimate_ms = 5;  ///< the job's own estimate until a slice has been measured
  int64_t submitted_ns = 0;
  int64_t last_admitted_ns = -1;  ///< -1: never started
  bool in_slice = false;          ///< admitted, its slice not yet finished (holds a lane)
  bool started() const { return last_admitted_ns >= 0; }
};

enum class Verdict {
  kRun,   ///< run one slice now
  kWait,  ///< no slack now: ask again later (a started job is paused)
  kShed,  ///< give up the job (not started, or cancelled)
};

struct SchedulerCounters {
  uint64_t frames_in = 0, frames_processed = 0, frames_dropped = 0, deadline_misses = 0;
  uint64_t jobs_submitted = 0, slices_admitted = 0, jobs_completed = 0, jobs_shed_unstarted = 0, jobs_cancelled = 0,
           slices_paused = 0;
};

class Scheduler {
 public:
  explicit Scheduler(const SchedulerParams& params = {});

  const SchedulerParams& params() const { return params_; }
  int64_t periodNs() const { return period_ns_; }

  // Frontend thread.
  void frameArrived(int64_t arrival_ns);
  /// Stale frames skipped (the consumer took the newest).
  void framesDropped(size_t n);
  void frameStarted(int64_t now_ns, int64_t arrival_ns);
  /// Per-stage costs of the frame in ms (FrontendStage order, kTotal may be
  /// 0: then the sum). True when the frame met its deadline.
  bool frameFinished(int64_t now_ns, const std::array<double, 4>& stage_ms, double total_ms = 0);
  /// Pose-feedback effort level for the next window (0 = skip).
  int feedbackEffort() const { return feedback_effort_.load(std::memory_order_relaxed); }

  // Background threads.
  void jobSubmitted(JobTicket& job, int64_t now_ns);
  /// May `job` run one slice now? `predicted_ms` receives the slice cost the
  /// decision assumed.
  Verdict admitSlice(JobTicket& job, int64_t now_ns, double* predicted_ms = nullptr);
  /// A slice of `job` ran for `ms` (its lane is free again; a slice run
  /// without admission, e.g. one that could not be given up, is measured
  /// all the same).
  void sliceFinished(JobTicket& job, double ms);
  void jobFinished(const JobTicket& job);

  /// Changes whenever a frame finishes; background threads that were told kWait block
  /// in waitForFrameEnd(epoch) instead of polling (each wake-up of a polling
  /// thread preempts a frontend thread on a small machine).
  uint64_t frameEpoch() const { return epoch_.load(std::memory_order_acquire); }
  /// Blocks until a frame finishes (or wakeAll is called) after `epoch` was read.
  void waitForFrameEnd(uint64_t epoch) const { epoch_.wait(epoch, std::memory_order_acquire); }
  /// Wakes every waiter, also one about to wait (shutdown).
  void wakeAll() {
    epoch_.fetch_add(1, std::memory_order_release);
    epoch_.notify_all();
  }

  /// Background slices running now (admitted, not yet finished).
  int runningSlices() const { return running_.load(std::memory_order_relaxed); }
  int backgroundLanes() const { return lanes_; }

  /// Predicted slack of the current period at `now_ns`, ms (may be negative).
  double slackMs(int64_t now_ns) const;

  SchedulerCounters counters() const;
  const CostModel& cost(FrontendStage s) const { return stages_[static_cast<size_t>(s)]; }
  /// Table of counters and per-stage p50/p99 for the final report.
  std::string report() const;

 private:
  /// DESIGN: a kind's slices are planned with max(EWMA, the largest slice
  /// that started within the last recent_frames periods), not the largest
  /// of its last recent_frames slices as the frontend's stages are. A
  /// slice is only measured when one is admitted: with a window of slices,
  /// one slow slice (25 ms, preempted) set the prediction above any slack a
  /// 25 FPS frame leaves, no slice was admitted again, and every later
  /// refinement job of the run was cancelled (quality room, 150 frames: 10
  /// iteration slices in all, the last at 0.5 s of 6 s). With time, the
  /// outlier ages out and the EWMA, which weighs it by alpha, plans again.
  ///
  /// DESIGN: a kind with no slice within the horizon is planned with an
  /// EWMA that nothing updates any more (a slice is only measured when one
  /// is admitted). When that EWMA is above what the kind's own slices
  /// usually cost (the median of its last recent_frames slices; with fewer
  /// than kEvidenceSlices slices, the lower of that and what its jobs
  /// declare), it decays towards it, halving the gap every horizon.
  /// Without this, a kind whose first slice was an outlier never ran again: the first ROI job's setup, in a process
  /// that had not run one yet, took 17-30 ms of CPU where later setups of the same size took 2-7 ms, and every later
  /// job of the run was shed before it started (whole fr1/xyz at 30 FPS: 39 made, 1 completed). A kind that really
  /// costs more than the slack is admitted again once the gap has shrunk into the slack, its slow slice measured anew,
  /// and then held back for a horizon again, until its own slices outvote the jobs' declaration (kEvidenceSlices
  /// slices: then its median is what it usually costs).
  static constexpr size_t kEvidenceSlices = 3;
  struct JobKindCost {
    std::string kind;
    CostModel model;
    std::vector<std::pair<int64_t, double>> recent;  ///< (slice start, ms), within the horizon
    int64_t newest_ns = 0;                           ///< start of the newest slice measured
  };
  /// Predicted slice cost of a kind at now_ns (the job's estimate when unmeasured); job_mutex_ held.
  double predictSliceLocked(const JobTicket& job, int64_t now_ns) const;
  static double recentMaxSince(const JobKindCost& k, int64_t since_ns);
  /// Takes a background lane if one is free.
  bool takeLane();

  SchedulerParams params_;
  int64_t period_ns_;
  int64_t margin_ns_;
  /// DESIGN: the slack is time the frontend leaves free on every core, so
  /// one background slice per core fits it; a slice beyond that shares a
  /// core with another and runs past its predicted end.
  int lanes_;
  std::atomic<int> running_{0};
  // Frontend-owned.
  std::array<CostModel, static_cast<size_t>(FrontendStage::kCount)> stages_;
  int64_t current_arrival_ns_ = 0;
  // Shared with background threads.
  std::atomic<int64_t> next_due_ns_{0};          ///< when the next frame is due
  std::atomic<int64_t> frame_end_pred_ns_{0};    ///< predicted end of the frame in progress
  std::atomic<int64_t> last_arrival_ns_{-1};     ///< newest frame arrival
  std::atomic<int64_t> started_arrival_ns_{-1};  ///< arrival of the newest frame started
  std::atomic<int64_t> frontend_pred_ns_{0};     ///< predicted frontend cost per frame
  std::atomic<int> feedback_effort_;
  std::atomic<uint64_t> epoch_{0};  ///< bumped when a frame ends and by wakeAll
  std::atomic<uint64_t> frames_in_{0}, frames_processed_{0}, frames_dropped_{0}, misses_{0};
  std::atomic<uint64_t> jobs_submitted_{0}, slices_admitted_{0}, jobs_completed_{0}, shed_unstarted_{0}, cancelled_{0},
      paused_{0};
  // Background side: job costs by kind, under a mutex (touched once per
  // slice by background threads, never by the frontend's per-frame path).
  mutable std::mutex job_mutex_;
  std::vector<JobKindCost> job_costs_;
  std::atomic<double> feedback_full_ms_{0.0};  ///< predicted "feedback" slice at full effort
};

}  // namespace hxmap::rt
