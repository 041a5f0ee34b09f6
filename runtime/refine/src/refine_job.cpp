#include "hxmap/refine/refine_job.hpp"

#include <algorithm>
#include <chrono>

namespace hxmap::rt {

RefineOutcome runRefineJob(const RefineJob& job, const alg::ImplicitParams& params, RefineBudget budget,
                           alg::RefineProbe* probe) {
  using Clock = std::chrono::steady_clock;
  auto ms = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  RefineOutcome out;
  out.job_id = job.id;
  out.map_epoch = job.map_epoch;
  const auto t0 = Clock::now();
  alg::RoiRefiner refiner(*job.snapshot, job.roi.box_world, job.keyframes, params);
  refiner.setProbe(probe);
  const auto t1 = Clock::now();
  while (refiner.iterate(std::max(1, params.slice_iterations))) {
    if (budget == RefineBudget::kIterationsAndTime && ms(t1, Clock::now()) >= params.time_budget_ms) {
      out.out_of_time = true;
      break;
    }
  }
  const auto t2 = Clock::now();
  out.result = refiner.result();
  if (job.implicit_surface && refiner.iterations() > 0)
    out.surface = std::make_shared<alg::FieldSurface>(refiner.field(), 3.0f, &refiner.seen());
  const auto t3 = Clock::now();
  out.setup_ms = ms(t0, t1), out.train_ms = ms(t1, t2), out.result_ms = ms(t2, t3);
  return out;
}

}  // namespace hxmap::rt
