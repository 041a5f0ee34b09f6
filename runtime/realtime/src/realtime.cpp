#include "hxmap/runtime/realtime.hpp"

#include <pthread.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <deque>
#include <memory>
#include <thread>

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "hxmap/runtime/latest_slot.hpp"
#include "hxmap/runtime/spsc_ring.hpp"

namespace hxmap::rt {

namespace {

using Clock = std::chrono::steady_clock;

void nameThisThread(const char* name) { pthread_setname_np(pthread_self(), name); }

// Lowers the calling thread's priority (Linux nice values are per thread).
// Failure is logged, not fatal: the thread then runs at the process's.
void niceThisThread(const char* name, int nice) {
  if (nice <= 0) return;
  const auto tid = static_cast<id_t>(::syscall(SYS_gettid));
  if (::setpriority(PRIO_PROCESS, tid, nice) != 0) {
    spdlog::warn("{}: could not set nice {}: {}", name, nice, std::strerror(errno));
  }
}

double percentileOf(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(std::lround(q * static_cast<double>(v.size() - 1))))];
}

}  // namespace

void traceFrameStages(TraceRecorder& trace, const FrameResult& result, int64_t start_ns, int thread, int64_t frame) {
  int64_t t = start_ns;
  for (int s = 0; s < kStageCount; ++s) {
    if (result.stage_ms[s] <= 0) continue;
    const auto d = static_cast<int64_t>(result.stage_ms[s] * 1e6);
    trace.add({stageName(s), "frontend", t, d, thread, frame, result.stamp_ns});
    t += d;
  }
}

PlaybackSource::PlaybackSource(const std::vector<RgbdFrame>& frames, double fps) : frames_(frames), due_ns_(frames.size()) {
  for (size_t i = 0; i < frames.size(); ++i) {
    due_ns_[i] = fps > 0 ? static_cast<int64_t>(std::llround(static_cast<double>(i) * 1e9 / fps))
                         : frames[i].stamp_ns - frames[0].stamp_ns;
  }
  if (fps > 0) {
    fps_ = fps;
  } else if (frames.size() > 1 && due_ns_.back() > 0) {
    fps_ = static_cast<double>(frames.size() - 1) * 1e9 / static_cast<double>(due_ns_.back());
  }
}

Expected<std::optional<RgbdFrame>> PlaybackSource::next(const std::atomic<bool>& stop) {
  const int64_t now = std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
  if (next_ == 0) t0_ns_ = now;
  if (next_ >= frames_.size() || stop.load()) return std::optional<RgbdFrame>{};
  // Sleep in short steps so a stop is seen even across a long gap in the stamps.
  const Clock::time_point due{std::chrono::nanoseconds(t0_ns_ + due_ns_[next_])};
  while (Clock::now() < due && !stop.load()) std::this_thread::sleep_until(std::min(due, Clock::now() + std::chrono::milliseconds(50)));
  if (stop.load()) return std::optional<RgbdFrame>{};
  return std::optional<RgbdFrame>{frames_[next_++]};  // cv::Mat copies share the pixels
}

RealtimeStats runRealtime(const std::vector<RgbdFrame>& frames, Frontend& frontend, const RealtimeOptions& options,
                          const std::atomic<bool>& stop, TraceRecorder* trace, const std::function<void()>& heartbeat) {
  if (frames.empty()) return {};
  PlaybackSource source(frames, options.fps);
  return runRealtime(source, frontend, options, stop, trace, heartbeat);
}

RealtimeStats runRealtime(FrameSource& source, Frontend& frontend, const RealtimeOptions& options,
                          const std::atomic<bool>& stop, TraceRecorder* trace, const std::function<void()>& heartbeat) {
  RealtimeStats stats;
  SchedulerParams sp = options.scheduler;
  if (source.fps() > 0) sp.target_fps = source.fps();
  Scheduler sched(sp);

  const Clock::time_point t0 = Clock::now();
  auto now_ns = [&] { return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - t0).count(); };

  // A frame with its arrival time and its index in the run (moved through
  // the slot; the images are shared, never copied).
  struct Arrival {
    RgbdFrame frame;
    int64_t arrival_ns = 0;
    int64_t index = 0;
  };
  LatestSlot<Arrival> sensor_slot;
  std::atomic<uint64_t> published{0};
  std::atomic<bool> sensor_done{false}, frontend_done{false}, workers_stop{false};
  // A background thread reads a counter, then looks for work, then sleeps
  // until the counter moves. The stop flag is read after the counter: the
  // shutdown sets it before bumping every counter, so a thread that read
  // the bumped value sees the flag here and does not sleep (read before
  // the counter, the flag could be missed and the thread sleep forever).
  auto waitUnlessStopping = [&workers_stop](std::atomic<uint64_t>& counter, uint64_t seen) {
    if (!workers_stop.load()) counter.wait(seen, std::memory_order_acquire);
  };
  // The same for the scheduler's frame epoch (wakeAll bumps it).
  auto waitForFrameEndUnlessStopping = [&workers_stop, &sched](uint64_t epoch) {
    if (!workers_stop.load()) sched.waitForFrameEnd(epoch);
  };
  int64_t first_arrival_ns = 0, last_arrival_ns = 0;  // sensor thread until joined
  std::string source_error;                            // sensor thread until joined
  // Pose feedback: keyframes (images shared, not copied) to the feedback
  // thread, keyframe corrections back.
  SpscRing<FeedbackInput> keyframes(16);
  // Map copies the feedback thread is done with, back to the frontend's
  // thread for reuse (the ring orders the solver's reads before the next
  // copy's writes).
  SpscRing<std::shared_ptr<const alg::TsdfMap>> snapshots_done(16);
  // ROI refinement: jobs from the frontend to each worker, outcomes back
  // (one ring per direction and worker: single producer, single consumer).
  // Outcomes and pose corrections are applied by the frontend between
  // frames, so it stays the map's only writer.
  const bool burn = options.burn_slice_ms > 0;
  const int n_workers = std::max(0, options.refine_workers);
  std::vector<std::unique_ptr<SpscRing<RefineJob>>> job_rings;
  std::vector<std::atomic<int>> jobs_in_flight(static_cast<size_t>(std::max(0, options.refine_workers)));  ///< queued or running
  std::vector<std::unique_ptr<SpscRing<RefineOutcome>>> outcome_rings;
  for (int w = 0; w < n_workers; ++w) {
    job_rings.push_back(std::make_unique<SpscRing<RefineJob>>(4));
    outcome_rings.push_back(std::make_unique<SpscRing<RefineOutcome>>(8));
  }
  std::atomic<uint64_t> jobs_pushed{0};
  std::atomic<uint64_t> refine_slices{0}, refine_done{0}, refine_shed{0}, outcomes_full{0};
  uint64_t refine_submitted = 0, refine_rejected = 0, voxels_written = 0;  // frontend thread
  size_t next_worker = 0;                                                 // frontend thread
  const alg::ImplicitParams implicit = frontend.params().implicit;
  SpscRing<KeyframeCorrection> corrections(64);
  const alg::FeedbackParams feedback_params = frontend.params().feedback;
  std::atomic<uint64_t> corrections_full{0}, windows_skipped{0}, windows_shed{0};
  FeedbackTally feedback_tally;  // feedback thread until joined
  uint64_t patches_applied = 0, corrections_applied = 0;  // frontend thread
  // Refinement outcomes into the map: the frontend thread between frames,
  // the calling thread once the threads are joined.
  auto applyOutcomes = [&] {
    for (auto& ring : outcome_rings) {
      RefineOutcome outcome;
      while (ring->tryPop(outcome)) {
        const alg::PatchStats ps = frontend.applyRefinement(outcome);
        patches_applied += ps.applied > 0;
        voxels_written += ps.applied;
      }
    }
  };
  // Loop closure: the loop closer moves to its own thread; keyframes go
  // to it (those the ring has no room for wait on the frontend thread:
  // none may be lost, the graph needs every one), corrections with their
  // rebuilt maps come back and are applied between frames.
  std::unique_ptr<LoopCloser> closer = frontend.detachLoopCloser();
  if (closer) closer->setParallel(options.loop_parallel ? options.loop_parallel : ParallelFor(serialFor));
  SpscRing<LoopKeyframe> loop_keyframes(32);
  SpscRing<LoopCorrection> loop_corrections(4);
  std::deque<LoopKeyframe> loop_backlog;  // frontend thread
  std::vector<alg::WindowKeyframe> feedback_backlog;  // frontend thread: keyframes waiting for a map copy
  std::deque<LoopCorrection> loop_unsent;  // loop thread until joined: corrections the ring had no room for
  std::atomic<uint64_t> loop_pushed{0}, loop_slices{0}, loop_forced{0}, loop_waits{0};
  uint64_t loop_applied = 0;  // frontend thread
  double loop_apply_ms = 0;   // frontend thread
  std::atomic<uint64_t> keyframes_pushed{0};
  std::atomic<uint64_t> keyframes_full{0}, keyframes_seen{0}, burn_slices{0}, frames_done{0};
  std::vector<double> latency_ms, frontend_ms;  // frontend thread only until joined
  latency_ms.reserve(source.size());
  frontend_ms.reserve(source.size());
  stats.results.reserve(source.size());

  // The sensor starts once the frontend has warmed up on its own thread
  // (Frontend::warmUp; the thread's allocator arena is then grown too).
  std::atomic<bool> frontend_ready{!options.warm_up};
  std::thread sensor([&] {
    nameThisThread("hx-sensor");
    frontend_ready.wait(false);
    for (int64_t i = 0; !stop.load(); ++i) {
      auto next = source.next(stop);
      if (!next) {
        source_error = next.message();
        spdlog::error("{}", source_error);
        break;
      }
      if (!next->has_value()) break;  // the end of the stream, or stopped
      Arrival a{std::move(**next), now_ns(), i};
      if (i == 0) first_arrival_ns = a.arrival_ns;
      last_arrival_ns = a.arrival_ns;
      sched.frameArrived(a.arrival_ns);
      if (sensor_slot.publish(std::move(a))) {
        sched.framesDropped(1);
        spdlog::debug("frame {} replaced an unprocessed one (dropped)", i);
      }
      published.fetch_add(1, std::memory_order_release);
      published.notify_one();
    }
    sensor_done.store(true);
    published.fetch_add(1, std::memory_order_release);  // wake the frontend
    published.notify_one();
  });

  std::thread frontend_thread([&] {
    nameThisThread("hx-frontend");
    if (options.warm_up) {
      struct Ready {  // released however the warm-up ends
        std::atomic<bool>& flag;
        ~Ready() {
          flag.store(true);
          flag.notify_all();
        }
      } ready{frontend_ready};
      frontend.warmUp();
    }
    while (true) {
      // Read the publish count before looking: a frame published after the
      // look changes it, so the wait below cannot miss it.
      const uint64_t seen = published.load(std::memory_order_acquire);
      Arrival a;
      if (!sensor_slot.take(a)) {
        if (sensor_done.load()) break;
        published.wait(seen, std::memory_order_acquire);
        continue;
      }
      // Between frames: what background threads sent back.
      applyOutcomes();
      KeyframeCorrection correction;
      while (corrections.tryPop(correction)) corrections_applied += frontend.applyKeyframeCorrection(correction);
      LoopCorrection loop;
      while (loop_corrections.tryPop(loop)) {
        const int64_t t = now_ns();
        frontend.applyLoopCorrection(loop);
        loop_apply_ms += static_cast<double>(now_ns() - t) * 1e-6;
        ++loop_applied;
        loop = LoopCorrection{};  // the old map goes here, not in the next frame
      }
      // DESIGN: a keyframe makes refinement jobs only for idle workers.
      // Made while every worker was busy, a job waited behind others for
      // seconds (a job is about 1 s of CPU, run in the slack of 2-3 frames
      // per period) with the ROI, keyframes and poses of its time, or found
      // the rings full and was rejected: in 25 FPS playback of the quality
      // room 24-28 of 33 jobs were rejected. Left to a later keyframe, the
      // ROI is chosen afresh from newer scores and the job starts at once.
      int budget = 0;
      for (int w = 0; w < n_workers && !burn; ++w) budget += jobs_in_flight[static_cast<size_t>(w)].load() == 0;
      frontend.setRefineBudget(budget);
      const int64_t start = now_ns();
      sched.frameStarted(start, a.arrival_ns);
      FrameResult r = frontend.process(a.frame);
      const double r_integrate_ms = r.stage_ms[kIntegrate];
      const int64_t end = now_ns();
      sched.frameFinished(end, {r.stage_ms[0], r.stage_ms[1], r.stage_ms[2], r.stage_ms[3]},
                          static_cast<double>(end - start) * 1e-6);
      latency_ms.push_back(static_cast<double>(end - a.arrival_ns) * 1e-6);
      frontend_ms.push_back(static_cast<double>(end - start) * 1e-6);
      if (trace) traceFrameStages(*trace, r, start, 2, a.index);
      if (options.on_frame) {
        const SchedulerCounters c = sched.counters();
        options.on_frame(r, frontend,
                         RunCounters{c.frames_dropped, c.deadline_misses, refine_done.load(), refine_shed.load(),
                                     latency_ms.back()});
      }
      // ROI jobs the keyframe made: to the workers in turn; when every
      // worker's ring is full the job is rejected and counted.
      for (RefineJob& job : frontend.takeRefineJobs()) {
        bool pushed = false;
        for (int k = 0; k < n_workers && !pushed && !burn; ++k) {
          const size_t w = (next_worker + static_cast<size_t>(k)) % static_cast<size_t>(n_workers);
          jobs_in_flight[w].fetch_add(1);
          pushed = job_rings[w]->tryPush(std::move(job));
          if (pushed) {
            next_worker = w + 1;
          } else {
            jobs_in_flight[w].fetch_sub(1);
          }
        }
        ++(pushed ? refine_submitted : refine_rejected);
        if (pushed) {
          jobs_pushed.fetch_add(1, std::memory_order_release);
          jobs_pushed.notify_all();
        }
      }
      // The feedback thread solves on a copy of the map around the window,
      // made after a frame with the slack for it (a keyframe's own frame
      // seldom has it): the keyframes wait for it here.
      for (std::shared_ptr<const alg::TsdfMap> done; snapshots_done.tryPop(done);) {
        frontend.reuseFeedbackSnapshot(done.get());
      }
      for (alg::WindowKeyframe& kf : frontend.takeFeedbackKeyframes()) feedback_backlog.push_back(std::move(kf));
      if (!feedback_backlog.empty()) {
        const FeedbackCounters fc = frontend.feedbackCounters();
        const double copy_ms = fc.snapshots > 0 ? fc.snapshot_ms / static_cast<double>(fc.snapshots) : 4.0;
        if (sched.slackMs(now_ns()) > 1.5 * copy_ms) {
          const std::shared_ptr<const alg::TsdfMap> snapshot = frontend.feedbackSnapshot();
          for (alg::WindowKeyframe& kf : feedback_backlog) {
            if (!keyframes.tryPush({std::move(kf), snapshot})) keyframes_full.fetch_add(1);
          }
          feedback_backlog.clear();
          keyframes_pushed.fetch_add(1, std::memory_order_release);
          keyframes_pushed.notify_one();
        }
      }
      for (LoopKeyframe& kf : frontend.takeLoopKeyframes()) loop_backlog.push_back(std::move(kf));
      bool loop_sent = false;
      while (!loop_backlog.empty() && loop_keyframes.tryPush(std::move(loop_backlog.front()))) {
        loop_backlog.pop_front();
        loop_sent = true;
      }
      if (loop_sent) {
        loop_pushed.fetch_add(1, std::memory_order_release);
        loop_pushed.notify_one();
      }
      stats.results.push_back(std::move(r));
      frames_done.fetch_add(1, std::memory_order_relaxed);
      // A keyframe that feedback moved is re-integrated here, after the
      // frame, one per frame and only into predicted slack (it costs about
      // two integrations).
      if (frontend.reintegrationsPending() > 0) {
        const FeedbackCounters fc = frontend.feedbackCounters();
        const double cost_ms = fc.reintegrations > 0 ? fc.reintegrate_ms / static_cast<double>(fc.reintegrations)
                                                     : 2.0 * std::max(1.0, r_integrate_ms);
        if (sched.slackMs(now_ns()) > 1.5 * cost_ms) frontend.reintegratePending(1);
      }
    }
    frontend_done.store(true);
  });

  // Pose feedback (paper 3.4): new keyframes join the window, then the
  // window is solved in scheduler-admitted slices (one keyframe's
  // evaluation each), on the map copy that came with the newest keyframe,
  // with as many LM
  // iterations as the scheduler's effort level allows (0: the window waits
  // for the next keyframe). Corrections go back to the frontend.
  std::thread feedback([&] {
    nameThisThread("hx-feedback");
    niceThisThread("hx-feedback", options.background_nice);
    FeedbackSolver solver(feedback_params);
    std::shared_ptr<const alg::TsdfMap> snapshot;
    alg::FeedbackMaps maps;
    // The refined regions' fields (shared: a field lives while a solve uses it).
    std::vector<std::shared_ptr<const alg::ImplicitSurface>> surfaces;
    const int max_effort = std::max(1, sp.max_feedback_effort);
    FeedbackInput in;
    while (!workers_stop.load()) {
      const uint64_t seen = keyframes_pushed.load(std::memory_order_acquire);
      bool added = false;
      while (keyframes.tryPop(in)) {
        if (snapshot && snapshot != in.map) {
          // Done with the previous copy: no queued keyframe refers to it.
          if (!snapshots_done.tryPush(std::move(snapshot))) snapshot.reset();
        }
        snapshot = std::move(in.map);
        maps.tsdf = snapshot.get();
        solver.add(std::move(in.keyframe), maps);
        keyframes_seen.fetch_add(1);
        added = true;
      }
      if (!added) {
        waitUnlessStopping(keyframes_pushed, seen);  // no polling
        continue;
      }
      const int effort = sched.feedbackEffort();
      if (effort <= 0) {
        windows_skipped.fetch_add(1);
        continue;
      }
      const int iterations =
          std::max(1, (feedback_params.iterations * std::min(effort, max_effort) + max_effort - 1) / max_effort);
      JobTicket ticket{"feedback", 2.0};
      sched.jobSubmitted(ticket, now_ns());
      bool shed = false, in_slice = false;
      int64_t slice_start = 0;
      auto endSlice = [&] {
        if (!in_slice) return;
        const int64_t t = now_ns();
        sched.sliceFinished(ticket, static_cast<double>(t - slice_start) * 1e-6);
        if (trace) trace->add({"feedback", "background", slice_start, t - slice_start, 3 + n_workers, -1, -1});
        in_slice = false;
      };
      auto stopSolve = [&] {
        endSlice();
        while (!workers_stop.load()) {
          const uint64_t epoch = sched.frameEpoch();
          const Verdict v = sched.admitSlice(ticket, now_ns());
          if (v == Verdict::kRun) {
            in_slice = true;
            slice_start = now_ns();
            return false;
          }
          if (v == Verdict::kShed) {
            shed = true;
            return true;
          }
          waitForFrameEndUnlessStopping(epoch);
        }
        return true;
      };
      surfaces = frontend.implicitSurfaces();
      maps.implicit.clear();
      for (const auto& sf : surfaces) maps.implicit.push_back(sf.get());
      const std::vector<KeyframeCorrection> out = solver.solve(maps, stopSolve, iterations);
      endSlice();
      if (shed) {
        windows_shed.fetch_add(1);
      } else {
        sched.jobFinished(ticket);
      }
      for (const KeyframeCorrection& c : out) {
        if (!corrections.tryPush(c)) corrections_full.fetch_add(1);
      }
    }
    while (keyframes.tryPop(in)) keyframes_seen.fetch_add(1);
    feedback_tally = solver.tally();
  });

  // Loop closure (paper: the explicit backbone's loop closure): the loop
  // closer's steps, each a scheduler-admitted slice. A comparison the
  // scheduler sheds is given up (the next keyframe brings another); what
  // may not be given up (a keyframe's place in the graph, a rebuild after
  // a solve) runs one step when shed, at most once per shed period.
  std::thread loop_thread;
  if (closer) {
    loop_thread = std::thread([&] {
      nameThisThread("hx-loop");
      niceThisThread("hx-loop", options.background_nice);
      JobTicket ticket;
      bool in_job = false;
      LoopKeyframe kf;
      while (!workers_stop.load()) {
        const uint64_t seen = loop_pushed.load(std::memory_order_acquire);
        while (loop_keyframes.tryPop(kf)) closer->add(withOwnImages(std::move(kf)));
        if (!closer->busy()) {
          waitUnlessStopping(loop_pushed, seen);  // no polling
          continue;
        }
        if (!in_job) {
          ticket = JobTicket{"loop", 5.0};
          sched.jobSubmitted(ticket, now_ns());
          in_job = true;
        }
        ticket.kind = closer->rebuilding() ? "loop rebuild" : "loop";
        const uint64_t epoch = sched.frameEpoch();
        const Verdict v = sched.admitSlice(ticket, now_ns());
        if (v == Verdict::kWait) {
          loop_waits.fetch_add(1);
          waitForFrameEndUnlessStopping(epoch);
          continue;
        }
        if (v == Verdict::kShed) {
          // What cannot be given up (a keyframe's place in the graph with
          // its odometry check, a rebuild once the graph has moved) runs
          // one step now, then waits on under a new ticket: at most one
          // such step per shed period. DESIGN: leaving it to wait only, or
          // taking the queued keyframes in with tracking's motion
          // unchecked, left the synthetic loop at 4.3-8.7 cm in real time
          // (1.5-1.9 cm with this step); the unchecked path is kept for a
          // queue beyond max_pending (LoopCloser::shed).
          in_job = false;
          if (closer->shed()) continue;
          loop_forced.fetch_add(1);
        }
        const int64_t s0 = now_ns();
        closer->step();
        const int64_t s1 = now_ns();
        sched.sliceFinished(ticket, static_cast<double>(s1 - s0) * 1e-6);
        loop_slices.fetch_add(1);
        if (trace) trace->add({ticket.kind.c_str(), "background", s0, s1 - s0, 3 + n_workers + 1, -1, -1});
        if (std::optional<LoopCorrection> c = closer->takeCorrection()) loop_unsent.push_back(std::move(*c));
        while (!loop_unsent.empty() && loop_corrections.tryPush(std::move(loop_unsent.front()))) loop_unsent.pop_front();
        if (in_job && !closer->busy()) {
          sched.jobFinished(ticket);
          in_job = false;
        }
      }
    });
  }

  // One ROI job on worker w, in scheduler-admitted slices: the field's
  // setup, then slice_iterations iterations at a time, then the write-back.
  // Shed (no slack for too long) or stopped: the job is dropped, the map
  // keeps its fused values.
  auto runJob = [&](int w, RefineJob& job) {
    JobTicket ticket{"refine setup", 10.0};
    sched.jobSubmitted(ticket, now_ns());
    std::unique_ptr<alg::RoiRefiner> refiner;
    RefineOutcome outcome;
    outcome.job_id = job.id;
    outcome.map_epoch = job.map_epoch;
    while (!workers_stop.load()) {
      // Each phase's slices have their own cost model: a setup slice costs
      // several iterations, and one cost for both would keep iterations out
      // of slack they fit in.
      const bool training = refiner && !refiner->finished() && outcome.train_ms < implicit.time_budget_ms;
      ticket.kind = !refiner ? "refine setup" : training ? "refine" : "refine write-back";
      const uint64_t epoch = sched.frameEpoch();
      const Verdict v = sched.admitSlice(ticket, now_ns());
      if (v == Verdict::kWait) {
        waitForFrameEndUnlessStopping(epoch);
        continue;
      }
      if (v == Verdict::kShed) {
        refine_shed.fetch_add(1);
        return;
      }
      const int64_t s0 = now_ns();
      enum { kSetup, kTrain, kWriteBack } phase = kTrain;
      if (!refiner) {
        refiner = std::make_unique<alg::RoiRefiner>(*job.snapshot, job.roi.box_world, job.keyframes, implicit);
        phase = kSetup;
      } else if (training) {
        refiner->iterate(std::max(1, implicit.slice_iterations));
      } else {
        outcome.out_of_time = !refiner->finished();
        outcome.result = refiner->result();
        if (refiner->iterations() > 0) outcome.surface = std::make_shared<alg::FieldSurface>(refiner->field(), 3.0f, &refiner->seen());
        phase = kWriteBack;
      }
      const int64_t s1 = now_ns();
      const double ms = static_cast<double>(s1 - s0) * 1e-6;
      sched.sliceFinished(ticket, ms);
      refine_slices.fetch_add(1);
      if (trace) trace->add({ticket.kind.c_str(), "background", s0, s1 - s0, 3 + w, -1, -1});
      (phase == kSetup ? outcome.setup_ms : phase == kTrain ? outcome.train_ms : outcome.result_ms) += ms;
      if (phase == kWriteBack) {
        sched.jobFinished(ticket);
        refine_done.fetch_add(1);
        if (!outcome_rings[static_cast<size_t>(w)]->tryPush(std::move(outcome))) outcomes_full.fetch_add(1);
        return;
      }
    }
  };

  std::vector<std::thread> workers;
  for (int w = 0; w < n_workers; ++w) {
    workers.emplace_back([&, w] {
      const std::string name = fmt::format("hx-refine-{}", w);
      nameThisThread(name.c_str());
      niceThisThread(name.c_str(), options.background_nice);
      if (!burn) {
        RefineJob job;
        while (!workers_stop.load()) {
          const uint64_t seen = jobs_pushed.load(std::memory_order_acquire);
          if (job_rings[static_cast<size_t>(w)]->tryPop(job)) {
            runJob(w, job);
            job = RefineJob{};  // release the snapshot and images now
            jobs_in_flight[static_cast<size_t>(w)].fetch_sub(1);
            continue;
          }
          waitUnlessStopping(jobs_pushed, seen);  // no polling
        }
        return;
      }
      JobTicket job{"burn", options.burn_slice_ms};
      int done = 0;
      sched.jobSubmitted(job, now_ns());
      volatile double sink = 0;
      while (!workers_stop.load()) {
        const uint64_t epoch = sched.frameEpoch();
        const Verdict v = sched.admitSlice(job, now_ns());
        if (v == Verdict::kWait) {
          waitForFrameEndUnlessStopping(epoch);  // slack changes when a frame ends
          continue;
        }
        if (v == Verdict::kShed || done == options.burn_slices_per_job) {
          if (v != Verdict::kShed) sched.jobFinished(job);
          job = JobTicket{"burn", options.burn_slice_ms};
          done = 0;
          sched.jobSubmitted(job, now_ns());
          continue;
        }
        const int64_t s0 = now_ns(), s_end = s0 + static_cast<int64_t>(options.burn_slice_ms * 1e6);
        while (now_ns() < s_end) {  // burn the CPU
          for (int k = 0; k < 1000; ++k) sink = sink + std::sqrt(static_cast<double>(k) + sink * 1e-9);
        }
        const int64_t s1 = now_ns();
        sched.sliceFinished(job, static_cast<double>(s1 - s0) * 1e-6);
        burn_slices.fetch_add(1);
        ++done;
        if (trace) trace->add({"burn", "background", s0, s1 - s0, 3 + w, -1, -1});
      }
      (void)sink;
    });
  }

  // Status line and stop handling on the calling thread.
  const auto wall0 = Clock::now();
  auto last_status = Clock::now();
  uint64_t last_done = 0;
  const bool tty = isatty(STDERR_FILENO) != 0;
  while (!frontend_done.load()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (stop.load()) stats.stopped_early = true;  // the sensor stops; the frontend drains and ends
    const double since = std::chrono::duration<double>(Clock::now() - last_status).count();
    const double interval = options.status_interval_s > 0 ? options.status_interval_s : 0.5;
    if (since >= interval) {
      if (heartbeat) heartbeat();
    }
    if (options.status_interval_s > 0 && since >= options.status_interval_s) {
      const uint64_t done = frames_done.load();
      const SchedulerCounters c = sched.counters();
      const std::string of = source.size() > 0 ? fmt::format(" of {}", source.size()) : std::string();
      const std::string line = fmt::format(
          "realtime: {:5.1f} FPS, {}{} frames, dropped {}, deadline misses {}, ROI jobs done {}, shed jobs {}",
          static_cast<double>(done - last_done) / since, done, of, c.frames_dropped, c.deadline_misses,
          refine_done.load(), c.jobs_shed_unstarted + c.jobs_cancelled);
      if (tty) {
        std::fprintf(stderr, "\r%s   ", line.c_str());
      } else {
        std::fprintf(stderr, "%s\n", line.c_str());
      }
      last_done = done;
    }
    if (since >= interval) last_status = Clock::now();
  }
  sensor.join();
  frontend_thread.join();
  workers_stop.store(true);
  sched.wakeAll();
  jobs_pushed.fetch_add(1, std::memory_order_release);
  jobs_pushed.notify_all();
  keyframes_pushed.fetch_add(1, std::memory_order_release);
  keyframes_pushed.notify_all();
  loop_pushed.fetch_add(1, std::memory_order_release);
  loop_pushed.notify_all();
  for (auto& w : workers) w.join();
  feedback.join();
  if (loop_thread.joinable()) loop_thread.join();
  if (closer) {
    // What was still queued or under way: finished here (the threads are
    // joined), so the graph holds every keyframe and a last closure still
    // corrects the trajectory written.
    LoopKeyframe kf;
    while (loop_keyframes.tryPop(kf)) closer->add(std::move(kf));
    for (LoopKeyframe& k : loop_backlog) closer->add(std::move(k));
    for (LoopKeyframe& k : frontend.takeLoopKeyframes()) closer->add(std::move(k));
    LoopCorrection loop;
    while (loop_corrections.tryPop(loop)) frontend.applyLoopCorrection(loop);
    for (LoopCorrection& c : loop_unsent) frontend.applyLoopCorrection(c);
    while (closer->step()) {
      if (std::optional<LoopCorrection> c = closer->takeCorrection()) frontend.applyLoopCorrection(*c);
    }
    frontend.attachLoopCloser(std::move(closer));
  }
  // Outcomes that arrived after the last frame: applied now (the threads
  // are joined), so no finished refinement is lost.
  applyOutcomes();
  if (tty && options.status_interval_s > 0) std::fputc('\n', stderr);

  stats.wall_s = std::chrono::duration<double>(Clock::now() - wall0).count();
  stats.counters = sched.counters();
  stats.source_error = source_error;
  const double played_s =
      std::max(1e-9, static_cast<double>(last_arrival_ns - first_arrival_ns) * 1e-9 + sched.periodNs() * 1e-9);
  stats.fps = static_cast<double>(stats.counters.frames_processed) / std::min(stats.wall_s, played_s);
  stats.latency_p50_ms = percentileOf(latency_ms, 0.5);
  stats.latency_p99_ms = percentileOf(latency_ms, 0.99);
  stats.frontend_p50_ms = percentileOf(frontend_ms, 0.5);
  stats.frontend_p99_ms = percentileOf(frontend_ms, 0.99);
  stats.burn_slices_run = burn_slices.load();
  stats.keyframes_to_feedback = keyframes_seen.load();
  stats.patches_applied = patches_applied;
  stats.corrections_applied = corrections_applied;
  stats.feedback_ring_full = keyframes_full.load();
  stats.refine_jobs_submitted = refine_submitted;
  stats.refine_jobs_rejected = refine_rejected;
  stats.refine_jobs_completed = refine_done.load();
  stats.refine_jobs_shed = refine_shed.load();
  stats.refine_outcomes_dropped = outcomes_full.load();
  stats.refine_slices = refine_slices.load();
  stats.refine_voxels_written = voxels_written;
  const SchedulerCounters& c = stats.counters;
  stats.report = fmt::format(
      "realtime run at {:.1f} FPS (deadline {:.1f} ms), {} threads: sensor, frontend, feedback, {} refinement{}\n"
      "  frames: in {}, processed {}, dropped {}, deadline misses {}\n"
      "  sustained {:.1f} FPS; latency arrival->pose p50 {:.1f} ms, p99 {:.1f} ms; frontend p50 {:.1f} ms, p99 {:.1f} ms\n"
      "  background: {} jobs submitted, {} completed, {} shed before start, {} cancelled; {} slices paused\n"
      "  ROI refinement: {} jobs made, {} to workers ({} rejected: rings full), {} completed and written back "
      "({:.0f}%), {} shed, {} still queued or running at the end; {} slices, {} voxels written\n"
      "  burn load: {} slices ({:.0f} ms of CPU)\n"
      "  keyframes to pose feedback: {} (ring full {} times); applied between frames: {} map patches, {} keyframe "
      "corrections\n",
      sp.target_fps, sched.periodNs() * 1e-6, 3 + static_cast<int>(workers.size()) + (frontend.loopCloser() ? 1 : 0),
      workers.size(), frontend.loopCloser() ? ", loop closure" : "", c.frames_in,
      c.frames_processed, c.frames_dropped, c.deadline_misses, stats.fps, stats.latency_p50_ms, stats.latency_p99_ms,
      stats.frontend_p50_ms, stats.frontend_p99_ms, c.jobs_submitted, c.jobs_completed, c.jobs_shed_unstarted,
      c.jobs_cancelled, c.slices_paused, refine_submitted + refine_rejected, refine_submitted, refine_rejected,
      stats.refine_jobs_completed,
      refine_submitted ? 100.0 * static_cast<double>(stats.refine_jobs_completed) / static_cast<double>(refine_submitted)
                       : 0.0,
      stats.refine_jobs_shed, refine_submitted - stats.refine_jobs_completed - stats.refine_jobs_shed, stats.refine_slices,
      voxels_written, stats.burn_slices_run, static_cast<double>(stats.burn_slices_run) * options.burn_slice_ms,
      stats.keyframes_to_feedback, stats.feedback_ring_full, stats.patches_applied,
      stats.corrections_applied);
  if (feedback_params.enabled) {
    stats.feedback_windows_skipped = windows_skipped.load();
    stats.feedback_windows_shed = windows_shed.load();
    stats.feedback_windows_solved = feedback_tally.windows;
    stats.feedback_corrections_sent = feedback_tally.corrections_sent;
    stats.report += "  " + feedback_tally.text(frontend.feedbackCounters(), feedback_params);
    stats.report += fmt::format("  feedback windows skipped at effort 0: {}, cut short by the scheduler: {}; "
                                "corrections lost (ring full): {}\n",
                                stats.feedback_windows_skipped, stats.feedback_windows_shed, corrections_full.load());
  }
  if (frontend.loopCloser()) {
    const LoopClosureCounters lc = frontend.loopClosureCounters();
    stats.report += fmt::format("  loop closure: {} slices, waited for slack {} times; shed: {} comparisons or "
                                "keyframes taken in unchecked; {} steps run when shed (nothing to give up); {} corrections "
                                "applied between frames ({:.1f} ms each)\n",
                                loop_slices.load(), loop_waits.load(), lc.shed, loop_forced.load(), loop_applied,
                                loop_applied ? loop_apply_ms / static_cast<double>(loop_applied) : 0.0);
  }
  if (const std::string st = source.statsText(); !st.empty()) stats.report += "  source: " + st + "\n";
  if (!source_error.empty()) stats.report += "  the source failed: " + source_error + "\n";
  return stats;
}

}  // namespace hxmap::rt
