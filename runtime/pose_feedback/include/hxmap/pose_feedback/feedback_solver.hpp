// Pose feedback (paper 3.4) as a runner drives it: keyframes from the
// frontend into a sliding window, a solve, corrections back; with the
// figures for the run's summary.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/feedback/params.hpp"
#include "hxmap/feedback/window.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt {

/// What applying corrections did, summed over a run.
struct FeedbackCounters {
  uint64_t corrections = 0;       ///< keyframe corrections applied
  uint64_t corrections_late = 0;  ///< for keyframes no longer kept (ignored)
  uint64_t reintegrations = 0;    ///< keyframes de-integrated and integrated at the new pose
  uint64_t reintegrations_pending = 0;
  double reintegrate_ms = 0;  ///< total
  uint64_t snapshots = 0;     ///< map copies for a feedback thread (feedbackSnapshot)
  uint64_t snapshot_blocks = 0;
  double snapshot_ms = 0;  ///< total
};

/// A keyframe for a pose-feedback solver on another thread, with the map
/// copy to solve on (Frontend::feedbackSnapshot; shared by the keyframes
/// handed over together).
struct FeedbackInput {
  alg::WindowKeyframe keyframe;
  std::shared_ptr<const alg::TsdfMap> map;
};

/// Pose feedback's estimate of a keyframe's pose.
struct KeyframeCorrection {
  uint32_t keyframe_id = 0;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
};

/// Pose feedback's figures for a run's summary.
struct FeedbackTally {
  uint64_t windows = 0, stopped = 0, failed = 0;
  uint64_t corrections_sent = 0;  ///< keyframe estimates that stood out of the solve's noise
  /// Of the estimates that stood out, how many were checked densely
  /// (FeedbackParams::verify_stride) and refused there, and the checks' time.
  uint64_t verified = 0, refused = 0;
  double verify_ms = 0;
  std::vector<double> solve_ms;            ///< per solved window, without the stop callback's waits
  double cost_before = 0, cost_after = 0;  ///< summed over windows
  /// Residuals at the solution, summed over windows: explicit (TSDF) and
  /// implicit (refined regions' fields), photometric + depth.
  uint64_t explicit_residuals = 0, implicit_residuals = 0;
  void add(const alg::SolveReport& report, double ms);
  /// Lines for the run summary (with the frontend's correction counters).
  std::string text(const FeedbackCounters& counters, const alg::FeedbackParams& params) const;
};

/// The pose-feedback window as the runtime drives it: keyframes in, a
/// solve, out the corrections that stand out of the solve's own noise
/// (FeedbackParams::min_correction_chi2, against the pose the frontend
/// has). One thread uses it (the offline loop or the real-time feedback
/// thread).
class FeedbackSolver {
 public:
  explicit FeedbackSolver(const alg::FeedbackParams& params) : window_(params) {}
  /// A keyframe from the frontend (takeFeedbackKeyframes), with its pose as
  /// the frontend has it.
  void add(alg::WindowKeyframe keyframe, const alg::FeedbackMaps& maps);
  /// Solves the window (`iterations` > 0 caps the LM iterations; `stop` as
  /// in PoseWindow::solve) and returns the corrections to send.
  std::vector<KeyframeCorrection> solve(const alg::FeedbackMaps& maps, const std::function<bool()>& stop = {},
                                        int iterations = 0);
  const FeedbackTally& tally() const { return tally_; }
  const alg::PoseWindow& window() const { return window_; }

 private:
  alg::PoseWindow window_;
  std::vector<std::pair<uint32_t, Eigen::Isometry3d>> published_;  ///< the frontend's pose per window keyframe
  FeedbackTally tally_;
};

}  // namespace hxmap::rt
