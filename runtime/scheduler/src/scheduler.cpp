#include "hxmap/scheduler/scheduler.hpp"

#include <algorithm>
#include <cmath>
#include <thread>

#include <fmt/format.h>

#include "hxmap/core/stamp.hpp"

namespace hxmap::rt {

void CostModel::add(double ms) {
  ewma_ = count_ == 0 ? ms : ewma_ + alpha_ * (ms - ewma_);
  ++count_;
  if (recent_.size() < window_) {
    recent_.push_back(ms);
  } else {
    recent_[next_] = ms;
    next_ = (next_ + 1) % window_;
  }
}

void CostModel::lowerEwma(double ms) { ewma_ = std::min(ewma_, ms); }

double CostModel::recentMax() const {
  double m = 0.0;
  for (double x : recent_) m = std::max(m, x);
  return m;
}

double CostModel::percentile(double q) const {
  if (recent_.empty()) return 0.0;
  std::vector<double> v = recent_;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(std::lround(std::clamp(q, 0.0, 1.0) * (v.size() - 1))));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

const char* frontendStageName(FrontendStage s) {
  switch (s) {
    case FrontendStage::kPreprocess: return "preprocess";
    case FrontendStage::kTrack: return "track";
    case FrontendStage::kIntegrate: return "integrate";
    case FrontendStage::kRaycast: return "raycast";
    case FrontendStage::kTotal: return "frontend";
    default: return "?";
  }
}

namespace {
double nsToMs(int64_t ns) { return static_cast<double>(ns) * 1e-6; }
}  // namespace

Scheduler::Scheduler(const SchedulerParams& params)
    : params_(params),
      period_ns_(static_cast<int64_t>(std::llround(1e9 / std::max(0.1, params.target_fps)))),
      margin_ns_(msToNs(params.margin_ms)),
      lanes_(params.background_lanes > 0 ? params.background_lanes
                                         : std::max(1, static_cast<int>(std::thread::hardware_concurrency()))),
      feedback_effort_(params.max_feedback_effort) {
  const size_t window = static_cast<size_t>(std::max(1, params.recent_frames));
  for (auto& s : stages_) s = CostModel(params.ewma_alpha, window);
}

void Scheduler::frameArrived(int64_t arrival_ns) {
  frames_in_.fetch_add(1, std::memory_order_relaxed);
  // The next frame is expected one period later: background work must leave
  // the CPUs by then.
  last_arrival_ns_.store(arrival_ns, std::memory_order_release);
  next_due_ns_.store(arrival_ns + period_ns_, std::memory_order_release);
}

void Scheduler::framesDropped(size_t n) { frames_dropped_.fetch_add(n, std::memory_order_relaxed); }

void Scheduler::frameStarted(int64_t now_ns, int64_t arrival_ns) {
  current_arrival_ns_ = arrival_ns;
  started_arrival_ns_.store(arrival_ns, std::memory_order_release);
  const double predicted = stages_[static_cast<size_t>(FrontendStage::kTotal)].predict();
  frame_end_pred_ns_.store(now_ns + msToNs(predicted), std::memory_order_release);
}

bool Scheduler::frameFinished(int64_t now_ns, const std::array<double, 4>& stage_ms, double total_ms) {
  double sum = 0;
  for (size_t s = 0; s < stage_ms.size(); ++s) {
    stages_[s].add(stage_ms[s]);
    sum += stage_ms[s];
  }
  stages_[static_cast<size_t>(FrontendStage::kTotal)].add(total_ms > 0 ? total_ms : sum);
  frontend_pred_ns_.store(msToNs(stages_[static_cast<size_t>(FrontendStage::kTotal)].predict()),
                          std::memory_order_release);
  frame_end_pred_ns_.store(now_ns, std::memory_order_release);
  frames_processed_.fetch_add(1, std::memory_order_relaxed);
  const bool met = now_ns <= current_arrival_ns_ + period_ns_;
  if (!met) misses_.fetch_add(1, std::memory_order_relaxed);

  // Pose-feedback effort follows the slack frames leave: down a level when
  // the last frame's slack cannot hold the current level, up when it holds
  // the next one with room to spare.
  const double feedback_full_ms = feedback_full_ms_.load(std::memory_order_relaxed);
  const double slack = nsToMs(current_arrival_ns_ + period_ns_ - margin_ns_ - now_ns);
  const int max_e = std::max(0, params_.max_feedback_effort);
  int e = feedback_effort_.load(std::memory_order_relaxed);
  const double per_level = max_e > 0 ? feedback_full_ms / max_e : 0.0;
  if (e > 0 && slack < per_level * e) {
    --e;
  } else if (e < max_e && slack > 1.5 * per_level * (e + 1)) {
    ++e;
  }
  feedback_effort_.store(e, std::memory_order_relaxed);
  wakeAll();  // background threads re-check their slack
  return met;
}

double Scheduler::slackMs(int64_t now_ns) const {
  int64_t busy_until = std::max(now_ns, frame_end_pred_ns_.load(std::memory_order_acquire));
  // A frame that has arrived but not started runs next, for its predicted cost.
  if (last_arrival_ns_.load(std::memory_order_acquire) > started_arrival_ns_.load(std::memory_order_acquire)) {
    busy_until += frontend_pred_ns_.load(std::memory_order_acquire);
  }
  return nsToMs(next_due_ns_.load(std::memory_order_acquire) - margin_ns_ - busy_until);
}

void Scheduler::jobSubmitted(JobTicket& job, int64_t now_ns) {
  job.submitted_ns = now_ns;
  job.last_admitted_ns = -1;
  jobs_submitted_.fetch_add(1, std::memory_order_relaxed);
}

double Scheduler::recentMaxSince(const JobKindCost& k, int64_t since_ns) {
  double m = 0.0;
  for (const auto& [t, ms] : k.recent) {
    if (t >= since_ns) m = std::max(m, ms);
  }
  return m;
}

double Scheduler::predictSliceLocked(const JobTicket& job, int64_t now_ns) const {
  const int64_t horizon = static_cast<int64_t>(std::max(1, params_.recent_frames)) * period_ns_;
  for (const auto& k : job_costs_) {
    if (k.kind != job.kind || k.model.empty()) continue;
    const double ewma = std::max(k.model.ewma(), 0.0);
    if (k.newest_ns >= now_ns - horizon) return std::max(ewma, recentMaxSince(k, now_ns - horizon));
    // Stale: see JobKindCost.
    const double median = k.model.percentile(0.5);
    const double usual = k.model.count() >= kEvidenceSlices ? median : std::min(job.slice_estimate_ms, median);
    if (ewma <= usual) return ewma;
    const double horizons = static_cast<double>(now_ns - horizon - k.newest_ns) / static_cast<double>(horizon);
    return usual + (ewma - usual) * std::exp2(-horizons);
  }
  return job.slice_estimate_ms;
}

Verdict Scheduler::admitSlice(JobTicket& job, int64_t now_ns, double* predicted_ms) {
  double predicted = 0;
  {
    std::lock_guard<std::mutex> lock(job_mutex_);
    predicted = predictSliceLocked(job, now_ns);
  }
  if (predicted_ms) *predicted_ms = predicted;
  // No prediction of the frontend yet (the first frames): no slack to give.
  const bool warm = frames_processed_.load(std::memory_order_acquire) >= static_cast<uint64_t>(params_.warmup_frames);
  if (warm && predicted <= slackMs(now_ns) && takeLane()) {
    job.last_admitted_ns = now_ns;
    job.in_slice = true;
    slices_admitted_.fetch_add(1, std::memory_order_relaxed);
    return Verdict::kRun;
  }
  // DESIGN: a started job waits longer than an unstarted one before it is
  // cancelled: long enough for one slow slice of its kind to leave the
  // recent maximum (recent_frames periods). Waiting costs nothing but the
  // worker; cancelling throws the job's work away. With the same patience
  // for both, one preempted slice (21.7 ms among slices of 7 ms, the first
  // iteration of a refinement job, 25 FPS quality room) kept the prediction
  // above the slack, and the job running was cancelled 8 periods later.
  // Six runs each, alternating, on a loaded machine: 13 of 22 jobs made
  // were shed and 3 completed; now none of 10 shed and 4 completed.
  const int64_t waiting_since = job.started() ? job.last_admitted_ns : job.submitted_ns;
  const int patience = params_.shed_after_periods + (job.started() ? std::max(1, params_.recent_frames) : 0);
  if (now_ns - waiting_since > static_cast<int64_t>(patience) * period_ns_) {
    (job.started() ? cancelled_ : shed_unstarted_).fetch_add(1, std::memory_order_relaxed);
    return Verdict::kShed;
  }
  if (job.started()) paused_.fetch_add(1, std::memory_order_relaxed);
  return Verdict::kWait;
}

bool Scheduler::takeLane() {
  int running = running_.load(std::memory_order_relaxed);
  while (running < lanes_) {
    if (running_.compare_exchange_weak(running, running + 1, std::memory_order_acq_rel)) return true;
  }
  return false;
}

void Scheduler::sliceFinished(JobTicket& job, double ms) {
  if (job.in_slice) {
    job.in_slice = false;
    running_.fetch_sub(1, std::memory_order_acq_rel);
  }
  std::lock_guard<std::mutex> lock(job_mutex_);
  auto it = std::find_if(job_costs_.begin(), job_costs_.end(), [&](const JobKindCost& k) { return k.kind == job.kind; });
  if (it == job_costs_.end()) {
    job_costs_.push_back({job.kind, CostModel(params_.ewma_alpha, static_cast<size_t>(std::max(1, params_.recent_frames))), {}});
    it = job_costs_.end() - 1;
  }
  // Timed by the slice's start (its admission); older than the horizon out.
  const int64_t t = std::max<int64_t>(job.last_admitted_ns, 0);
  const int64_t horizon = static_cast<int64_t>(std::max(1, params_.recent_frames)) * period_ns_;
  // A stale kind's EWMA goes on from what the slice was admitted with (its
  // decayed value), not from the value that held it back.
  if (!it->model.empty() && it->newest_ns < t - horizon) it->model.lowerEwma(predictSliceLocked(job, t));
  it->model.add(ms);
  it->recent.erase(std::remove_if(it->recent.begin(), it->recent.end(),
                                  [&](const auto& e) { return e.first < t - horizon; }),
                   it->recent.end());
  it->recent.emplace_back(t, ms);
  it->newest_ns = std::max(it->newest_ns, t);
  // The frontend reads the feedback cost once per frame: published lock-free.
  if (job.kind == "feedback") feedback_full_ms_.store(predictSliceLocked(job, t), std::memory_order_relaxed);
}

void Scheduler::jobFinished(const JobTicket&) { jobs_completed_.fetch_add(1, std::memory_order_relaxed); }

SchedulerCounters Scheduler::counters() const {
  SchedulerCounters c;
  c.frames_in = frames_in_.load();
  c.frames_processed = frames_processed_.load();
  c.frames_dropped = frames_dropped_.load();
  c.deadline_misses = misses_.load();
  c.jobs_submitted = jobs_submitted_.load();
  c.slices_admitted = slices_admitted_.load();
  c.jobs_completed = jobs_completed_.load();
  c.jobs_shed_unstarted = shed_unstarted_.load();
  c.jobs_cancelled = cancelled_.load();
  c.slices_paused = paused_.load();
  return c;
}

std::string Scheduler::report() const {
  const SchedulerCounters c = counters();
  std::string out = fmt::format(
      "frames: in {}, processed {}, dropped {}, deadline misses {} (deadline {:.1f} ms)\n"
      "jobs: submitted {}, completed {}, shed before start {}, cancelled {}; slices admitted {}, paused {}\n"
      "feedback effort now {} of {}\n"
      "stage costs, ms (last {} frames)   p50      p99\n",
      c.frames_in, c.frames_processed, c.frames_dropped, c.deadline_misses, nsToMs(period_ns_), c.jobs_submitted,
      c.jobs_completed, c.jobs_shed_unstarted, c.jobs_cancelled, c.slices_admitted, c.slices_paused, feedbackEffort(),
      params_.max_feedback_effort, params_.recent_frames);
  for (size_t s = 0; s < stages_.size(); ++s) {
    out += fmt::format("  {:<30} {:8.2f} {:8.2f}\n", frontendStageName(static_cast<FrontendStage>(s)),
                       stages_[s].percentile(0.5), stages_[s].percentile(0.99));
  }
  return out;
}

}  // namespace hxmap::rt
