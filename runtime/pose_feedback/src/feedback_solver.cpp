#include "hxmap/pose_feedback/feedback_solver.hpp"

#include <algorithm>
#include <chrono>

#include <fmt/format.h>

#include "hxmap/geometry/se3.hpp"

namespace hxmap::rt {

void FeedbackTally::add(const alg::SolveReport& report, double ms) {
  if (!report.failure.empty()) {
    ++failed;
    return;
  }
  ++windows;
  stopped += report.stopped;
  solve_ms.push_back(ms);
  cost_before += report.base_cost_before;
  cost_after += report.base_cost_after;
  explicit_residuals += static_cast<uint64_t>(report.after.photo_explicit + report.after.depth_explicit);
  implicit_residuals += static_cast<uint64_t>(report.after.photo_implicit + report.after.depth_implicit);
}

std::string FeedbackTally::text(const FeedbackCounters& c, const alg::FeedbackParams& p) const {
  if (!p.enabled) return "pose feedback: off\n";
  std::vector<double> v = solve_ms;
  std::sort(v.begin(), v.end());
  auto at = [&](double q) {
    return v.empty() ? 0.0 : v[static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5)];
  };
  return fmt::format(
             "pose feedback: window {}, {} windows solved ({} cut short), solve median {:.1f} ms, p90 {:.1f} ms "
             "(without "
             "waits for slack); cost "
             "{:.4g} -> {:.4g} (summed); residuals per window {:.0f} explicit, {:.0f} implicit (refined regions)\n"
             "  {} keyframe corrections sent ({} checked densely, {} refused there, {:.1f} ms per check), {} applied "
             "({} "
             "too late); {} keyframes re-integrated ({:.1f} ms each), {} waiting\n",
             p.window, windows, stopped, at(0.5), at(0.9), cost_before, cost_after,
             static_cast<double>(explicit_residuals) / static_cast<double>(std::max<uint64_t>(1, windows)),
             static_cast<double>(implicit_residuals) / static_cast<double>(std::max<uint64_t>(1, windows)),
             corrections_sent, verified, refused, verified ? verify_ms / static_cast<double>(verified) : 0.0,
             c.corrections, c.corrections_late, c.reintegrations,
             c.reintegrations ? c.reintegrate_ms / static_cast<double>(c.reintegrations) : 0.0,
             c.reintegrations_pending) +
         (c.snapshots == 0 ? std::string()
                           : fmt::format("  map copies for the feedback thread: {}, {:.0f} blocks and {:.2f} ms each "
                                         "(on the frontend's thread)\n",
                                         c.snapshots, static_cast<double>(c.snapshot_blocks) / c.snapshots,
                                         c.snapshot_ms / static_cast<double>(c.snapshots)));
}

void FeedbackSolver::add(alg::WindowKeyframe keyframe, const alg::FeedbackMaps& maps) {
  published_.emplace_back(keyframe.id, keyframe.T_world_cam);
  window_.add(std::move(keyframe), maps);
  // Forget the keyframes that slid out.
  const uint32_t oldest = window_.keyframes().front().id;
  published_.erase(
      std::remove_if(published_.begin(), published_.end(), [&](const auto& p) { return p.first < oldest; }),
      published_.end());
}

std::vector<KeyframeCorrection> FeedbackSolver::solve(const alg::FeedbackMaps& maps, const std::function<bool()>& stop,
                                                      int iterations) {
  std::vector<KeyframeCorrection> out;
  if (window_.size() == 0) return out;
  window_.setIterations(iterations > 0 ? iterations : window_.params().iterations);
  // The solve's own time: what the stop callback spends (a scheduler
  // waiting for slack between slices) is not the solver's.
  using Clock = std::chrono::steady_clock;
  double waited_ms = 0;
  std::function<bool()> timed_stop;
  if (stop) {
    timed_stop = [&] {
      const auto a = Clock::now();
      const bool halt = stop();
      waited_ms += std::chrono::duration<double, std::milli>(Clock::now() - a).count();
      return halt;
    };
  }
  const auto t0 = Clock::now();
  const alg::SolveReport rep = window_.solve(maps, timed_stop);
  tally_.add(rep, std::chrono::duration<double, std::milli>(Clock::now() - t0).count() - waited_ms);
  if (!rep.failure.empty()) return out;
  const auto& kfs = window_.keyframes();
  for (size_t j = 0; j < kfs.size() && j < rep.marginal_information.size(); ++j) {
    auto it = std::find_if(published_.begin(), published_.end(), [&](const auto& p) { return p.first == kfs[j].id; });
    if (it == published_.end()) continue;
    const alg::Vector6d d = alg::logSE3(it->second.inverse() * kfs[j].T_world_cam);
    const double chi2 = d.dot(rep.marginal_information[j] * d);
    if (!(chi2 > window_.params().min_correction_chi2)) continue;
    if (window_.params().require_channel_agreement && j < rep.channels_agree.size() && !rep.channels_agree[j]) continue;
    if (window_.params().verify_stride > 0) {
      // In slices, as the solve's casts: a correction not checked to the end
      // is not sent (the next solve finds it again).
      const double waited_before = waited_ms;
      const auto v0 = Clock::now();
      const alg::PoseWindow::Verification v = window_.verify(j, it->second, kfs[j].T_world_cam, maps, timed_stop);
      tally_.verify_ms +=
          std::chrono::duration<double, std::milli>(Clock::now() - v0).count() - (waited_ms - waited_before);
      if (v.stopped) break;
      ++tally_.verified;
      if (!v.passed) {
        ++tally_.refused;
        continue;
      }
    }
    it->second = kfs[j].T_world_cam;
    out.push_back({kfs[j].id, kfs[j].T_world_cam});
  }
  tally_.corrections_sent += out.size();
  return out;
}

}  // namespace hxmap::rt
