// ROI refinement jobs (paper 3.3) as the frontend hands them out: self
// contained, so any thread can run one, and their outcomes for the map's
// writer.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "hxmap/feedback/field_surface.hpp"
#include "hxmap/implicit/params.hpp"
#include "hxmap/implicit/refine.hpp"
#include "hxmap/quality/quality.hpp"
#include "hxmap/refine/params.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::rt {

/// One ROI refinement, self-contained: a copy of the ROI's blocks and the
/// images of the keyframes that see it, so a worker thread never touches
/// the frontend's map.
struct RefineJob {
  uint64_t id = 0;
  uint32_t keyframe_id = 0;  ///< the keyframe whose scoring chose the ROI
  uint64_t map_epoch = 0;    ///< the map it was cut from (a loop closure rebuilds the map)
  alg::Roi roi;
  std::shared_ptr<const alg::TsdfMap> snapshot;
  std::vector<alg::KeyframeImages> keyframes;
  /// Sample the trained field for pose feedback's implicit channels
  /// (RefineOutcome::surface): only when feedback reads them.
  bool implicit_surface = true;
};

/// A job's outcome, for the map's writer.
struct RefineOutcome {
  uint64_t job_id = 0;
  uint64_t map_epoch = 0;  ///< the job's
  alg::RefineResult result;
  double setup_ms = 0;       ///< field initialization and ray collection
  double train_ms = 0;       ///< the iterations
  double result_ms = 0;      ///< write-back and sigma_Neural
  bool out_of_time = false;  ///< stopped by params.time_budget_ms
  /// The trained field as the pose feedback's implicit surface (sampled
  /// once, timed in result_ms); null when the job had nothing to learn or
  /// was made without RefineJob::implicit_surface.
  std::shared_ptr<const alg::FieldSurface> surface;
};

/// Whether a job run to its end also stops at params.time_budget_ms of
/// wall time (benchmarks, to bound a job's cost) or only at its iteration
/// cap (offline runs: the same input then gives the same map and
/// trajectory on any machine and under any load).
enum class RefineBudget { kIterationsAndTime, kIterationsOnly };

/// Runs a job to its end on the calling thread (offline runs and
/// benchmarks; the real-time runtime runs jobs in slices under its
/// scheduler instead).
/// `probe` (optional) is told the job's phases (bench_refine's breakdown).
RefineOutcome runRefineJob(const RefineJob& job, const alg::ImplicitParams& params,
                           RefineBudget budget = RefineBudget::kIterationsAndTime, alg::RefineProbe* probe = nullptr);

}  // namespace hxmap::rt
