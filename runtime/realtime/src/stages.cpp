#include "stages.hpp"

#include <pthread.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace hxmap::rt::stages {

void nameThisThread(const char* name) { pthread_setname_np(pthread_self(), name); }

void niceThisThread(const char* name, int nice) {
  if (nice <= 0) return;
  const auto tid = static_cast<id_t>(::syscall(SYS_gettid));
  if (::setpriority(PRIO_PROCESS, tid, nice) != 0) {
    spdlog::warn("{}: could not set nice {}: {}", name, nice, std::strerror(errno));
  }
}

// --------------------------------------------------------------- sensor

void SensorStage::start(const std::atomic<bool>& stop, const std::atomic<bool>& go) {
  thread_ = std::thread([this, &stop, &go] {
    nameThisThread("hx-sensor");
    go.wait(false);
    run(stop);
    out_.close();
  });
}

void SensorStage::run(const std::atomic<bool>& stop) {
  while (std::optional<Arrival> a = pull(stop)) {
    const int64_t i = a->index;
    if (out_.publish(std::move(*a))) {
      ctx_.sched.framesDropped(1);
      spdlog::debug("frame {} replaced an unprocessed one (dropped)", i);
    }
  }
}

std::optional<Arrival> SensorStage::pull(const std::atomic<bool>& stop) {
  if (stop.load()) return std::nullopt;
  const int64_t t0 = ctx_.nowNs();
  auto next = source_.next(stop);
  if (!next) {
    error = next.message();
    spdlog::error("{}", error);
    return std::nullopt;
  }
  if (!next->has_value()) return std::nullopt;  // the end of the stream, or stopped
  Arrival a{std::move(**next), ctx_.nowNs(), pulled_++};
  // A serial run reads each frame when it wants it: that is its load time
  // (a live source's next() waits for the frame's time instead).
  if (ctx_.serial && ctx_.trace) ctx_.trace->add({"load", "sensor", t0, a.arrival_ns - t0, 1, a.index, a.frame.stamp_ns});
  if (a.index == 0) first_arrival_ns = a.arrival_ns;
  last_arrival_ns = a.arrival_ns;
  ctx_.sched.frameArrived(a.arrival_ns);
  return a;
}

// ----------------------------------------------------------- refinement

bool RefineWorker::offer(RefineJob&& job) {
  in_flight_.fetch_add(1);
  if (!jobs_.tryPush(std::move(job))) {
    in_flight_.fetch_sub(1);
    return false;
  }
  bell_.ring();
  return true;
}

void RefineWorker::run() {
  const std::string name = fmt::format("hx-refine-{}", index_);
  nameThisThread(name.c_str());
  niceThisThread(name.c_str(), nice_);
  while (!ctx_.stopping.load()) {
    const uint32_t seen = bell_.read();
    if (in_flight_.load() > 0) {
      runQueued();
      continue;
    }
    bell_.wait(seen, ctx_.stopping);  // no polling
  }
}

void RefineWorker::runQueued() {
  for (RefineJob job; !ctx_.stopping.load() && jobs_.tryPop(job); job = RefineJob{}) {  // releases the snapshot
    runJob(job);
    in_flight_.fetch_sub(1);
  }
}

void RefineWorker::runJob(RefineJob& job) {
  Scheduler& sched = ctx_.sched;
  JobTicket ticket{"refine setup", 10.0};
  sched.jobSubmitted(ticket, ctx_.nowNs());
  std::unique_ptr<alg::RoiRefiner> refiner;
  RefineOutcome outcome;
  outcome.job_id = job.id;
  outcome.map_epoch = job.map_epoch;
  bool written = false;
  auto deliver = [&] {
    sched.jobFinished(ticket);
    counters_.done.fetch_add(1);
    if (!outcomes_.tryPush(std::move(outcome))) counters_.outcomes_full.fetch_add(1);
  };
  while (!ctx_.stopping.load()) {
    // Each phase's slices have their own cost model: a setup slice costs
    // several iterations, and one cost for both would keep iterations out
    // of slack they fit in.
    // A serial run trains to the iteration cap: no wall-clock budget.
    const bool training =
        refiner && !written && !refiner->finished() && (ctx_.serial || outcome.train_ms < params_.time_budget_ms);
    enum {
      kSetup,
      kTrain,
      kWriteBack,
      kSurface
    } phase = !refiner   ? kSetup
              : training ? kTrain
              : !written ? kWriteBack
                         : kSurface;
    static constexpr const char* kKinds[] = {"refine setup", "refine", "refine write-back", "refine surface"};
    ticket.kind = kKinds[phase];
    const uint64_t epoch = sched.frameEpoch();
    const Verdict v = ctx_.admit(ticket);
    if (v == Verdict::kWait) {
      ctx_.waitForFrameEnd(epoch);
      continue;
    }
    if (v == Verdict::kShed && phase == kSurface) {
      // Written back already: the map gets it, feedback goes without the field.
      counters_.surfaces_shed.fetch_add(1);
      deliver();
      return;
    }
    if (v == Verdict::kShed) {
      counters_.shed.fetch_add(1);
      return;
    }
    const int64_t s0 = ctx_.nowNs();
    switch (phase) {
      case kSetup:
        refiner = std::make_unique<alg::RoiRefiner>(*job.snapshot, job.roi.box_world, job.keyframes, params_);
        break;
      case kTrain:
        refiner->iterate(std::max(1, params_.slice_iterations));
        break;
      case kWriteBack:
        outcome.out_of_time = !refiner->finished();
        outcome.result = refiner->result();
        written = true;
        break;
      case kSurface:
        outcome.surface = std::make_shared<alg::FieldSurface>(refiner->field(), 3.0f, &refiner->seen());
        break;
    }
    const int64_t s1 = ctx_.nowNs();
    const double ms = static_cast<double>(s1 - s0) * 1e-6;
    sched.sliceFinished(ticket, ms);
    counters_.slices.fetch_add(1);
    if (ctx_.trace) ctx_.trace->add({ticket.kind.c_str(), "background", s0, s1 - s0, 3 + index_, -1, -1});
    (phase == kSetup ? outcome.setup_ms : phase == kTrain ? outcome.train_ms : outcome.result_ms) += ms;
    // The field is sampled in a slice of its own (see RefineJob::implicit_surface).
    const bool done =
        phase == kSurface || (phase == kWriteBack && !(job.implicit_surface && refiner->iterations() > 0));
    if (done) {
      deliver();
      return;
    }
  }
}

RefinePool::RefinePool(RunContext& ctx, int workers, const alg::ImplicitParams& params, int nice) : ctx_(ctx) {
  for (int w = 0; w < workers; ++w) workers_.push_back(std::make_unique<RefineWorker>(ctx, w, params, nice, counters));
}

void RefinePool::start() {
  for (auto& w : workers_) w->start();
}

void RefinePool::join() {
  for (auto& w : workers_) w->join();
}

int RefinePool::idleWorkers() const {
  return static_cast<int>(std::count_if(workers_.begin(), workers_.end(), [](const auto& w) { return w->idle(); }));
}

void RefinePool::submit(std::vector<RefineJob> jobs) {
  const size_t n = workers_.size();
  for (RefineJob& job : jobs) {
    bool pushed = false;
    for (size_t k = 0; k < n && !pushed; ++k) {
      const size_t w = (next_ + k) % n;
      pushed = workers_[w]->offer(std::move(job));
      if (!pushed && ctx_.serial) {
        workers_[w]->runQueued();
        pushed = workers_[w]->offer(std::move(job));
      }
      if (pushed) next_ = w + 1;
    }
    ++(pushed ? submitted : rejected);
  }
}

// ------------------------------------------------------------- feedback

FeedbackStage::FeedbackStage(RunContext& ctx, const Frontend& frontend, int max_effort, int nice, int lane)
    : ctx_(ctx),
      frontend_(frontend),
      params_(frontend.params().feedback),
      max_effort_(std::max(1, max_effort)),
      nice_(nice),
      lane_(lane),
      solver_(params_) {}

void FeedbackStage::offer(std::vector<alg::WindowKeyframe> keyframes, Frontend& frontend) {
  for (std::shared_ptr<const alg::TsdfMap> done; snapshots_done_.tryPop(done);)
    frontend.reuseFeedbackSnapshot(done.get());
  for (alg::WindowKeyframe& kf : keyframes) backlog_.push_back(std::move(kf));
  if (backlog_.empty()) return;
  const FeedbackCounters fc = frontend.feedbackCounters();
  const double copy_ms = fc.snapshots > 0 ? fc.snapshot_ms / static_cast<double>(fc.snapshots) : 4.0;
  if (ctx_.slackMs() <= 1.5 * copy_ms) return;
  const std::shared_ptr<const alg::TsdfMap> snapshot = frontend.feedbackSnapshot();
  for (alg::WindowKeyframe& kf : backlog_) {
    if (!keyframes_.tryPush({std::move(kf), snapshot})) ++keyframes_full;
  }
  backlog_.clear();
  bell_.ring();
}

void FeedbackStage::run() {
  nameThisThread("hx-feedback");
  niceThisThread("hx-feedback", nice_);
  while (!ctx_.stopping.load()) {
    const uint32_t seen = bell_.read();
    if (!solveQueued()) bell_.wait(seen, ctx_.stopping);  // no polling
  }
  for (FeedbackInput in; keyframes_.tryPop(in);) keyframes_seen.fetch_add(1);
}

bool FeedbackStage::solveQueued() {
  Scheduler& sched = ctx_.sched;
  bool added = false;
  alg::FeedbackMaps maps{snapshot_.get(), {}};
  for (FeedbackInput in; keyframes_.tryPop(in);) {
    if (snapshot_ && snapshot_ != in.map) {
      // Done with the previous copy: no queued keyframe refers to it.
      if (!snapshots_done_.tryPush(std::move(snapshot_))) snapshot_.reset();
    }
    snapshot_ = std::move(in.map);
    maps.tsdf = snapshot_.get();
    solver_.add(std::move(in.keyframe), maps);
    keyframes_seen.fetch_add(1);
    added = true;
  }
  if (!added) return false;
  const int effort = ctx_.serial ? max_effort_ : sched.feedbackEffort();
  if (effort <= 0) {
    windows_skipped.fetch_add(1);
    return true;
  }
  const int iterations =
      std::max(1, (params_.iterations * std::min(effort, max_effort_) + max_effort_ - 1) / max_effort_);
  JobTicket ticket{"feedback", 2.0};
  sched.jobSubmitted(ticket, ctx_.nowNs());
  bool shed = false, in_slice = false;
  int64_t slice_start = 0;
  auto endSlice = [&] {
    if (!in_slice) return;
    const int64_t t = ctx_.nowNs();
    sched.sliceFinished(ticket, static_cast<double>(t - slice_start) * 1e-6);
    if (ctx_.trace) ctx_.trace->add({"feedback", "background", slice_start, t - slice_start, lane_, -1, -1});
    in_slice = false;
  };
  // Called by the solver between its steps: true stops the solve.
  auto stopSolve = [&] {
    endSlice();
    while (!ctx_.stopping.load()) {
      const uint64_t epoch = sched.frameEpoch();
      const Verdict v = ctx_.admit(ticket);
      if (v == Verdict::kRun) {
        in_slice = true;
        slice_start = ctx_.nowNs();
        return false;
      }
      if (v == Verdict::kShed) {
        shed = true;
        return true;
      }
      ctx_.waitForFrameEnd(epoch);
    }
    return true;
  };
  // The refined regions' fields (shared: a field lives while the solve uses it).
  const std::vector<std::shared_ptr<const alg::ImplicitSurface>> surfaces = frontend_.implicitSurfaces();
  for (const auto& sf : surfaces) maps.implicit.push_back(sf.get());
  const std::vector<KeyframeCorrection> out = solver_.solve(maps, stopSolve, iterations);
  endSlice();
  if (shed) {
    windows_shed.fetch_add(1);
  } else {
    sched.jobFinished(ticket);
  }
  for (const KeyframeCorrection& c : out) {
    if (!corrections_.tryPush(c)) corrections_full.fetch_add(1);
  }
  return true;
}

// --------------------------------------------------------- loop closure

LoopStage::LoopStage(RunContext& ctx, Frontend& frontend, const ParallelFor& parallel, int nice, int lane)
    : ctx_(ctx),
      closer_(frontend.detachLoopCloser()),
      enabled_(closer_ != nullptr),
      describe_(frontend.params().relocalization.enabled),
      relocalization_(frontend.params().relocalization),
      nice_(nice),
      lane_(lane) {
  if (closer_) closer_->setParallel(parallel ? parallel : ParallelFor(serialFor));
  frontend.describeKeyframesElsewhere(describe_);
}

void LoopStage::start() {
  if (closer_ || describe_) thread_ = std::thread([this] { run(); });
}

void LoopStage::take(LoopKeyframe kf, bool own_images) {
  if (kf.describe) {
    const int64_t t0 = ctx_.nowNs();
    KeyframeFeatures f = describeKeyframe(kf, relocalization_);
    describe_ms.push_back(f.ms);
    unsent_features_.push_back(std::move(f));
    if (ctx_.trace) ctx_.trace->add({"keyframe features", "background", t0, ctx_.nowNs() - t0, lane_, -1, -1});
    sendFeatures();
  }
  if (closer_ && kf.close) closer_->add(own_images ? withOwnImages(std::move(kf)) : std::move(kf));
}

void LoopStage::sendFeatures() {
  while (!unsent_features_.empty() && features_.tryPush(std::move(unsent_features_.front()))) {
    unsent_features_.pop_front();
  }
}

bool LoopStage::takeFeatures(KeyframeFeatures& out) { return takeSent(features_, unsent_features_, out); }

void LoopStage::join() {
  bell_.ring();
  if (thread_.joinable()) thread_.join();
}

void LoopStage::offer(std::vector<LoopKeyframe> keyframes) {
  for (LoopKeyframe& kf : keyframes) backlog_.push_back(std::move(kf));
  bool sent = false;
  while (!backlog_.empty() && keyframes_.tryPush(std::move(backlog_.front()))) {
    backlog_.pop_front();
    sent = true;
  }
  if (sent) bell_.ring();
}

void LoopStage::run() {
  nameThisThread("hx-loop");
  niceThisThread("hx-loop", nice_);
  Scheduler& sched = ctx_.sched;
  JobTicket ticket;
  bool in_job = false;
  LoopKeyframe kf;
  while (!ctx_.stopping.load()) {
    const uint32_t seen = bell_.read();
    while (keyframes_.tryPop(kf)) take(std::move(kf));
    sendFeatures();
    if (!closer_ || !closer_->busy()) {
      bell_.wait(seen, ctx_.stopping);  // no polling
      continue;
    }
    if (!in_job) {
      ticket = JobTicket{"loop", 5.0};
      sched.jobSubmitted(ticket, ctx_.nowNs());
      in_job = true;
    }
    ticket.kind = closer_->rebuilding() ? "loop rebuild" : "loop";
    const uint64_t epoch = sched.frameEpoch();
    const Verdict v = ctx_.admit(ticket);
    if (v == Verdict::kWait) {
      waits.fetch_add(1);
      ctx_.waitForFrameEnd(epoch);
      continue;
    }
    if (v == Verdict::kShed) {
      // What cannot be given up (a keyframe's place in the graph with its
      // odometry check, a rebuild once the graph has moved) runs one step
      // now, then waits on under a new ticket: at most one such step per
      // shed period (waiting only, or taking keyframes in unchecked, left
      // the synthetic loop 2-5x worse in real time; the unchecked path is
      // kept for a queue beyond max_pending, LoopCloser::shed).
      in_job = false;
      if (closer_->shed()) continue;
      forced.fetch_add(1);
    }
    const int64_t s0 = ctx_.nowNs();
    closer_->step();
    const int64_t s1 = ctx_.nowNs();
    sched.sliceFinished(ticket, static_cast<double>(s1 - s0) * 1e-6);
    slices.fetch_add(1);
    if (ctx_.trace) ctx_.trace->add({ticket.kind.c_str(), "background", s0, s1 - s0, lane_, -1, -1});
    if (std::optional<LoopCorrection> c = closer_->takeCorrection()) unsent_.push_back(std::move(*c));
    while (!unsent_.empty() && corrections_.tryPush(std::move(unsent_.front()))) unsent_.pop_front();
    if (in_job && !closer_->busy()) {
      sched.jobFinished(ticket);
      in_job = false;
    }
  }
}

bool LoopStage::takeCorrection(LoopCorrection& out) { return takeSent(corrections_, unsent_, out); }

template <typename T>
bool LoopStage::takeSent(SpscRing<T>& ring, std::deque<T>& unsent, T& out) {
  if (ring.tryPop(out)) return true;
  if (!ctx_.serial || unsent.empty()) return false;
  out = std::move(unsent.front());  // one thread: what the ring had no room for
  unsent.pop_front();
  return true;
}

void LoopStage::stepQueued() {
  for (LoopKeyframe kf; keyframes_.tryPop(kf);) take(std::move(kf));
  if (!closer_) return;
  while (closer_->busy()) {
    const int64_t s0 = ctx_.nowNs();
    closer_->step();
    slices.fetch_add(1);
    if (ctx_.trace) ctx_.trace->add({"loop", "background", s0, ctx_.nowNs() - s0, lane_, -1, -1});
    if (std::optional<LoopCorrection> c = closer_->takeCorrection()) unsent_.push_back(std::move(*c));
  }
}

void LoopStage::finish(Frontend& frontend) {
  frontend.describeKeyframesElsewhere(false);
  LoopKeyframe kf;
  while (keyframes_.tryPop(kf)) take(std::move(kf), false);
  for (LoopKeyframe& k : backlog_) take(std::move(k), false);
  backlog_.clear();
  for (LoopKeyframe& k : frontend.takeLoopKeyframes()) take(std::move(k), false);
  for (KeyframeFeatures f; features_.tryPop(f);) frontend.addKeyframeFeatures(f);
  for (const KeyframeFeatures& f : unsent_features_) frontend.addKeyframeFeatures(f);
  unsent_features_.clear();
  if (!closer_) return;
  LoopCorrection loop;
  while (corrections_.tryPop(loop)) frontend.applyLoopCorrection(loop);
  for (LoopCorrection& c : unsent_) frontend.applyLoopCorrection(c);
  while (closer_->step()) {
    if (std::optional<LoopCorrection> c = closer_->takeCorrection()) frontend.applyLoopCorrection(*c);
  }
  frontend.attachLoopCloser(std::move(closer_));
}

// ------------------------------------------------------------- frontend

FrontendStage::FrontendStage(RunContext& ctx, Frontend& frontend, const RealtimeOptions& options, RefinePool& refine,
                             FeedbackStage& feedback, LoopStage& loop)
    : ctx_(ctx), frontend_(frontend), options_(options), refine_(refine), feedback_(feedback), loop_(loop) {
  ready_.store(!options.warm_up);
}

void FrontendStage::run() {
  nameThisThread("hx-frontend");
  if (options_.warm_up) {
    struct Ready {  // released however the warm-up ends
      std::atomic<bool>& flag;
      ~Ready() {
        flag.store(true);
        flag.notify_all();
      }
    } ready{ready_};
    frontend_.warmUp();
  }
  for (Arrival a; inbox_.take(a);) step(a);
  done_.store(true);
}

void FrontendStage::step(const Arrival& a) {
  applyBackgroundResults();
  FrameResult r = process(a);
  handOn();
  const FrameResult& kept = results.emplace_back(std::move(r));
  frames_done_.fetch_add(1, std::memory_order_relaxed);
  reintegrateIntoSlack(kept);
  // A map rebuilt by loop closure starts its own count.
  const uint64_t copied = frontend_.map().chunksCopiedOnWrite();
  chunks_copied_on_write += copied >= map_chunks_copied_seen_ ? copied - map_chunks_copied_seen_ : copied;
  map_chunks_copied_seen_ = copied;
  checkpointIntoSlack();
}

void FrontendStage::settle() {
  applyBackgroundResults();
  frontend_.reintegratePending();
}

void FrontendStage::applyOutcomes() {
  refine_.drainOutcomes([this](const RefineOutcome& outcome) {
    const alg::PatchStats ps = frontend_.applyRefinement(outcome);
    patches_applied += ps.applied > 0;
    voxels_written += ps.applied;
    if (options_.on_refined) options_.on_refined(outcome);
  });
}

// Between frames: what the background stages sent back.
void FrontendStage::applyBackgroundResults() {
  for (KeyframeFeatures f; loop_.takeFeatures(f);) frontend_.addKeyframeFeatures(f);
  applyOutcomes();
  for (KeyframeCorrection c; feedback_.takeCorrection(c);) corrections_applied += frontend_.applyKeyframeCorrection(c);
  for (LoopCorrection loop; loop_.takeCorrection(loop); loop = LoopCorrection{}) {  // the old map goes here
    const int64_t t = ctx_.nowNs();
    frontend_.applyLoopCorrection(loop);
    loop_apply_ms += static_cast<double>(ctx_.nowNs() - t) * 1e-6;
    ++loop_applied;
  }
}

FrameResult FrontendStage::process(const Arrival& a) {
  // A keyframe makes refinement jobs only for idle workers: a job queued
  // behind others ran seconds later with stale ROIs, or found the rings
  // full (24-28 of 33 jobs rejected in 25 FPS playback of the quality
  // room); left to a later keyframe, the ROI is chosen afresh.
  // A serial run's workers are always idle: its keyframes make every job.
  if (!ctx_.serial) frontend_.setRefineBudget(refine_.idleWorkers());
  Scheduler& sched = ctx_.sched;
  const int64_t start = ctx_.nowNs();
  sched.frameStarted(start, a.arrival_ns);
  Eigen::Isometry3d T_world_given;
  const bool given = options_.given_pose && options_.given_pose(a.frame, T_world_given);
  FrameResult r = frontend_.process(a.frame, given ? &T_world_given : nullptr);
  const int64_t end = ctx_.nowNs();
  sched.frameFinished(end, {r.stage_ms[0], r.stage_ms[1], r.stage_ms[2], r.stage_ms[3]},
                      static_cast<double>(end - start) * 1e-6);
  latency_ms.push_back(static_cast<double>(end - a.arrival_ns) * 1e-6);
  frontend_ms.push_back(static_cast<double>(end - start) * 1e-6);
  if (ctx_.trace) traceFrameStages(*ctx_.trace, r, start, 2, a.index);
  if (options_.on_frame) {
    const SchedulerCounters c = sched.counters();
    options_.on_frame(r, frontend_,
                      RunCounters{c.frames_dropped, ctx_.serial ? 0 : c.deadline_misses,
                                  refine_.counters.done.load(), refine_.counters.shed.load(), latency_ms.back()});
  }
  return r;
}

// After a frame: its ROI jobs to the workers, its keyframes to pose
// feedback and loop closure.
void FrontendStage::handOn() {
  refine_.submit(frontend_.takeRefineJobs());
  feedback_.offer(frontend_.takeFeedbackKeyframes(), frontend_);
  loop_.offer(frontend_.takeLoopKeyframes());
}

// A keyframe that feedback moved is re-integrated after a frame, one per
// frame and only into predicted slack (it costs about two integrations).
void FrontendStage::reintegrateIntoSlack(const FrameResult& r) {
  if (frontend_.reintegrationsPending() == 0) return;
  const FeedbackCounters fc = frontend_.feedbackCounters();
  const double cost_ms = fc.reintegrations > 0 ? fc.reintegrate_ms / static_cast<double>(fc.reintegrations)
                                               : 2.0 * std::max(1.0, r.stage_ms[kIntegrate]);
  if (ctx_.slackMs() > 1.5 * cost_ms) frontend_.reintegratePending(1);
}

void FrontendStage::checkpointIntoSlack() {
  if (!options_.on_checkpoint || options_.checkpoint_s <= 0) return;
  const int64_t now = ctx_.nowNs();
  if (last_checkpoint_ns_ < 0) last_checkpoint_ns_ = now;  // the first one an interval into the run
  const double due_s = static_cast<double>(now - last_checkpoint_ns_) * 1e-9 / options_.checkpoint_s;
  if (due_s < 1.0) return;
  // The copy's cost as last measured (5 ms before the first).
  const double cost_ms = checkpoint_copy_ms.empty() ? 5.0 : 1.2 * checkpoint_copy_ms.back();
  const bool forced = due_s >= 3.0;
  if (!forced && ctx_.slackMs() < cost_ms) return;
  MapCheckpoint c;
  c.map = std::make_shared<const alg::TsdfMap>(frontend_.mapSnapshot());
  c.details = frontend_.details();
  c.trajectory = frontend_.trajectory();
  const int64_t end = ctx_.nowNs();
  checkpoint_copy_ms.push_back(static_cast<double>(end - now) * 1e-6);
  checkpoints_forced += forced;
  if (ctx_.trace) ctx_.trace->add({"checkpoint copy", "frontend", now, end - now, 2, -1, -1});
  options_.on_checkpoint(std::move(c));
  last_checkpoint_ns_ = end;
}

}  // namespace hxmap::rt::stages
