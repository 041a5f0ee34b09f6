#include "hxmap/realtime/realtime.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "stages.hpp"

namespace hxmap::rt {

namespace {

using Clock = std::chrono::steady_clock;

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

PlaybackSource::PlaybackSource(const std::vector<RgbdFrame>& frames, double fps)
    : frames_(frames), due_ns_(frames.size()) {
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
  while (Clock::now() < due && !stop.load())
    std::this_thread::sleep_until(std::min(due, Clock::now() + std::chrono::milliseconds(50)));
  if (stop.load()) return std::optional<RgbdFrame>{};
  return std::optional<RgbdFrame>{frames_[next_++]};  // cv::Mat copies share the pixels
}

RealtimeStats runRealtime(const std::vector<RgbdFrame>& frames, Frontend& frontend, const RealtimeOptions& options,
                          const std::atomic<bool>& stop, TraceRecorder* trace, const std::function<void()>& heartbeat) {
  if (frames.empty()) return {};
  PlaybackSource source(frames, options.fps);
  return runRealtime(source, frontend, options, stop, trace, heartbeat);
}

namespace {

using stages::FeedbackStage;
using stages::LoopStage;
using stages::RefinePool;
using stages::RunContext;

// The calling thread while the stages run: the status line, the service
// heartbeat, and `stop` (the sensor stops; the frontend drains and ends).
bool watchRun(const RunContext& ctx, const FrameSource& source, const stages::FrontendStage& front,
              const RefinePool& refine, const RealtimeOptions& options, const std::atomic<bool>& stop,
              const std::function<void()>& heartbeat) {
  bool stopped = false;
  auto last_status = Clock::now();
  uint64_t last_done = 0;
  const bool tty = isatty(STDERR_FILENO) != 0;
  const double interval = options.status_interval_s > 0 ? options.status_interval_s : 0.5;
  while (!front.done()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    stopped = stopped || stop.load();
    const double since = std::chrono::duration<double>(Clock::now() - last_status).count();
    if (since < interval) continue;
    if (heartbeat) heartbeat();
    if (options.status_interval_s > 0) {
      const uint64_t done = front.framesDone();
      const SchedulerCounters c = ctx.sched.counters();
      const std::string of = source.size() > 0 ? fmt::format(" of {}", source.size()) : std::string();
      const std::string line = fmt::format(
          "realtime: {:5.1f} FPS, {}{} frames, dropped {}, deadline misses {}, ROI jobs done {}, shed jobs {}",
          static_cast<double>(done - last_done) / since, done, of, c.frames_dropped, c.deadline_misses,
          refine.counters.done.load(), c.jobs_shed_unstarted + c.jobs_cancelled);
      std::fprintf(stderr, tty ? "\r%s   " : "%s\n", line.c_str());
      last_done = done;
    }
    last_status = Clock::now();
  }
  if (tty && options.status_interval_s > 0) std::fputc('\n', stderr);
  return stopped;
}

// The run's figures and its report, once every stage is joined.
void summarize(RealtimeStats& stats, const RunContext& ctx, const stages::SensorStage& sensor,
               stages::FrontendStage& front, const RefinePool& refine, const BackgroundLoad* extra,
               const FeedbackStage& feedback, const LoopStage& loop, const Frontend& frontend,
               const FrameSource& source) {
  stats.counters = ctx.sched.counters();
  stats.source_error = sensor.error;
  const double played_s = std::max(
      1e-9, static_cast<double>(sensor.last_arrival_ns - sensor.first_arrival_ns) * 1e-9 + ctx.sched.periodNs() * 1e-9);
  stats.fps = static_cast<double>(stats.counters.frames_processed) / std::min(stats.wall_s, played_s);
  stats.latency_p50_ms = percentileOf(front.latency_ms, 0.5);
  stats.latency_p99_ms = percentileOf(front.latency_ms, 0.99);
  stats.frontend_p50_ms = percentileOf(front.frontend_ms, 0.5);
  stats.frontend_p99_ms = percentileOf(front.frontend_ms, 0.99);
  stats.keyframes_to_feedback = feedback.keyframes_seen.load();
  stats.patches_applied = front.patches_applied;
  stats.corrections_applied = front.corrections_applied;
  stats.feedback_ring_full = feedback.keyframes_full;
  stats.refine_jobs_submitted = refine.submitted;
  stats.refine_jobs_rejected = refine.rejected;
  stats.refine_jobs_completed = refine.counters.done.load();
  stats.refine_jobs_shed = refine.counters.shed.load();
  stats.refine_outcomes_dropped = refine.counters.outcomes_full.load();
  stats.refine_slices = refine.counters.slices.load();
  stats.refine_voxels_written = front.voxels_written;
  stats.checkpoints = front.checkpoint_copy_ms.size();
  stats.checkpoints_forced = front.checkpoints_forced;
  stats.checkpoint_copy_p50_ms = percentileOf(front.checkpoint_copy_ms, 0.5);
  stats.checkpoint_copy_max_ms = percentileOf(front.checkpoint_copy_ms, 1.0);
  stats.checkpoint_chunks_copied = front.chunks_copied_on_write;
  stats.results = std::move(front.results);
  const SchedulerCounters& c = stats.counters;
  const size_t background = refine.size();
  const uint64_t made = refine.submitted + refine.rejected;
  stats.report = fmt::format(
      "realtime run at {:.1f} FPS (deadline {:.1f} ms), {} threads: sensor, frontend, feedback, {} refinement{}\n"
      "  frames: in {}, processed {}, dropped {}, deadline misses {}\n"
      "  sustained {:.1f} FPS; latency arrival->pose p50 {:.1f} ms, p99 {:.1f} ms; frontend p50 {:.1f} ms, p99 {:.1f} "
      "ms\n"
      "  background: {} jobs submitted, {} completed, {} shed before start, {} cancelled; {} slices paused\n"
      "  ROI refinement: {} jobs made, {} to workers ({} rejected: rings full), {} completed and written back "
      "({:.0f}%), {} shed, {} still queued or running at the end; {} slices, {} voxels written\n"
      "  keyframes to pose feedback: {} (ring full {} times); applied between frames: {} map patches, {} keyframe "
      "corrections\n",
      ctx.sched.params().target_fps, ctx.sched.periodNs() * 1e-6,
      3 + background + (loop.enabled() || loop.describing() ? 1 : 0), background,
      loop.enabled() ? ", loop closure" : (loop.describing() ? ", keyframe features" : ""), c.frames_in,
      c.frames_processed, c.frames_dropped, c.deadline_misses, stats.fps, stats.latency_p50_ms, stats.latency_p99_ms,
      stats.frontend_p50_ms, stats.frontend_p99_ms, c.jobs_submitted, c.jobs_completed, c.jobs_shed_unstarted,
      c.jobs_cancelled, c.slices_paused, made, refine.submitted, refine.rejected, stats.refine_jobs_completed,
      refine.submitted
          ? 100.0 * static_cast<double>(stats.refine_jobs_completed) / static_cast<double>(refine.submitted)
          : 0.0,
      stats.refine_jobs_shed, refine.submitted - stats.refine_jobs_completed - stats.refine_jobs_shed,
      stats.refine_slices, stats.refine_voxels_written, stats.keyframes_to_feedback, stats.feedback_ring_full,
      stats.patches_applied, stats.corrections_applied);
  if (const uint64_t n = refine.counters.surfaces_shed.load(); n > 0) {
    stats.report += fmt::format(
        "  of those completed, {} without their field sampled for feedback's implicit channels (that slice shed)\n", n);
  }
  if (extra) stats.report += "  " + extra->reportLine() + "\n";
  if (stats.checkpoints > 0) {
    stats.report += fmt::format(
        "  checkpoints: {} map snapshots on the frontend thread ({} forced without slack), p50 {:.1f} ms, max {:.1f} "
        "ms; {} chunks of blocks ({:.1f} MiB) copied on write after them\n",
        stats.checkpoints, stats.checkpoints_forced, stats.checkpoint_copy_p50_ms, stats.checkpoint_copy_max_ms,
        stats.checkpoint_chunks_copied,
        static_cast<double>(stats.checkpoint_chunks_copied * alg::TsdfMap::chunkBlocks() * sizeof(alg::VoxelBlock)) /
            (1024.0 * 1024.0));
  }
  const alg::FeedbackParams& fp = frontend.params().feedback;
  if (fp.enabled) {
    stats.feedback_windows_skipped = feedback.windows_skipped.load();
    stats.feedback_windows_shed = feedback.windows_shed.load();
    stats.feedback_windows_solved = feedback.tally().windows;
    stats.feedback_corrections_sent = feedback.tally().corrections_sent;
    stats.feedback = feedback.tally();
    stats.report += "  " + feedback.tally().text(frontend.feedbackCounters(), fp);
    stats.report += fmt::format(
        "  feedback windows skipped at effort 0: {}, cut short by the scheduler: {}; "
        "corrections lost (ring full): {}\n",
        stats.feedback_windows_skipped, stats.feedback_windows_shed, feedback.corrections_full.load());
  }
  if (loop.enabled()) {
    const LoopClosureCounters lc = frontend.loopClosureCounters();
    stats.report += fmt::format(
        "  loop closure: {} slices, waited for slack {} times; shed: {} comparisons or "
        "keyframes taken in unchecked; {} steps run when shed (nothing to give up); {} corrections "
        "applied between frames ({:.1f} ms each)\n",
        loop.slices.load(), loop.waits.load(), lc.shed, loop.forced.load(), front.loop_applied,
        front.loop_applied ? front.loop_apply_ms / static_cast<double>(front.loop_applied) : 0.0);
  }
  if (loop.describing() && !loop.describe_ms.empty()) {
    stats.report +=
        fmt::format("  keyframe features (ORB, for relocalization{}): {} made {}, p50 {:.1f} ms, max {:.1f} ms\n",
                    loop.enabled() ? " and loop closure" : "", loop.describe_ms.size(),
                    ctx.serial ? "after their frames" : "on the background thread", percentileOf(loop.describe_ms, 0.5),
                    percentileOf(loop.describe_ms, 1.0));
  }
  if (const std::string st = source.statsText(); !st.empty()) stats.report += "  source: " + st + "\n";
  if (!sensor.error.empty()) stats.report += "  the source failed: " + sensor.error + "\n";
}

}  // namespace

RealtimeStats runRealtime(FrameSource& source, Frontend& frontend, const RealtimeOptions& options,
                          const std::atomic<bool>& stop, TraceRecorder* trace, const std::function<void()>& heartbeat) {
  SchedulerParams sp = options.scheduler;
  if (source.fps() > 0) sp.target_fps = source.fps();
  RunContext ctx(sp, trace);
  const int workers = std::max(0, options.refine_workers), nice = options.background_nice;

  // The stages, from the last to the first (each knows where its output goes).
  RefinePool refine(ctx, workers, frontend.params().refine.implicit, nice);
  FeedbackStage feedback(ctx, frontend, sp.max_feedback_effort, nice, 3 + workers);
  LoopStage loop(ctx, frontend, options.loop_parallel, nice, 3 + workers + 1);
  stages::FrontendStage front(ctx, frontend, options, refine, feedback, loop);
  stages::SensorStage sensor(ctx, source, front.inbox());

  refine.start();
  feedback.start();
  loop.start();
  if (options.extra_load) {
    options.extra_load->start(ctx.sched, [&ctx] { return ctx.nowNs(); }, ctx.stopping, trace);
  }
  front.start();
  sensor.start(stop, front.ready());  // once the frontend has warmed up

  const auto wall0 = Clock::now();
  RealtimeStats stats;
  stats.stopped_early = watchRun(ctx, source, front, refine, options, stop, heartbeat);
  sensor.join();
  front.join();
  ctx.stopBackground();
  refine.join();
  if (options.extra_load) options.extra_load->join();
  feedback.join();
  loop.join();
  // What the background stages finished after the last frame: applied now
  // (the threads are joined), so no result is lost.
  loop.finish(frontend);
  front.applyOutcomes();
  stats.wall_s = std::chrono::duration<double>(Clock::now() - wall0).count();
  summarize(stats, ctx, sensor, front, refine, options.extra_load, feedback, loop, frontend, source);
  return stats;
}

RealtimeStats runSerial(FrameSource& source, Frontend& frontend, const RealtimeOptions& options,
                        const std::atomic<bool>& stop, TraceRecorder* trace) {
  RunContext ctx(options.scheduler, trace, /*serial=*/true);
  RealtimeOptions serial = options;
  serial.warm_up = false;
  const int workers = std::max(1, options.refine_workers);

  RefinePool refine(ctx, workers, frontend.params().refine.implicit, 0);
  FeedbackStage feedback(ctx, frontend, options.scheduler.max_feedback_effort, 0, 3 + workers);
  LoopStage loop(ctx, frontend, options.loop_parallel, 0, 3 + workers + 1);
  stages::FrontendStage front(ctx, frontend, serial, refine, feedback, loop);
  stages::SensorStage sensor(ctx, source, front.inbox());

  const auto wall0 = Clock::now();
  RealtimeStats stats;
  while (!(options.should_stop && options.should_stop())) {
    std::optional<stages::Arrival> a = sensor.pull(stop);
    if (!a) break;
    front.step(*a);
    refine.runQueued();
    feedback.solveQueued();
    loop.stepQueued();
    front.settle();
  }
  stats.stopped_early = stop.load() || (options.should_stop && options.should_stop());
  loop.finish(frontend);
  front.applyOutcomes();
  stats.wall_s = std::chrono::duration<double>(Clock::now() - wall0).count();
  summarize(stats, ctx, sensor, front, refine, nullptr, feedback, loop, frontend, source);
  return stats;
}

}  // namespace hxmap::rt
