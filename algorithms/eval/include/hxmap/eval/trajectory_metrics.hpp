// Trajectory accuracy with the TUM RGB-D benchmark's semantics:
// associate by timestamp, align rigidly (Horn/Umeyama, no scale), RMSE of the
// translational differences (ATE); relative pose error over a fixed time
// delta (RPE).
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "hxmap/core/frame.hpp"

namespace hxmap::alg {

struct AssociationParams {
  int64_t max_difference_ns = 20'000'000;  ///< 0.02 s, as the benchmark's associate.py
  int64_t offset_ns = 0;                   ///< added to the second list's stamps
};

/// Greedy unique association of two stamp lists: all pairs closer than
/// max_difference_ns, closest first, each stamp used once (associate.py).
/// Returns index pairs (i in a, j in b) sorted by i.
std::vector<std::pair<size_t, size_t>> associateStamps(const std::vector<int64_t>& a, const std::vector<int64_t>& b,
                                                       const AssociationParams& params = {});

/// Rigid transform T (no scale) minimizing sum |T * src_i - dst_i|^2.
Eigen::Isometry3d alignRigid(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst);

struct AteResult {
  size_t pairs = 0;
  double rmse_m = 0, mean_m = 0, median_m = 0, max_m = 0;
  Eigen::Isometry3d T_gt_est = Eigen::Isometry3d::Identity();  ///< alignment applied to the estimate
};

struct RpeResult {
  size_t pairs = 0;
  double trans_rmse_m = 0, rot_rmse_deg = 0;
};

/// Absolute trajectory error. Fewer than 3 associated pairs gives pairs = 0.
AteResult computeAte(const Trajectory& estimate, const Trajectory& ground_truth, const AssociationParams& params = {});

/// Relative pose error over pairs of estimate poses `delta_ns` apart (the
/// first estimate pose at least delta_ns after each one), against the
/// associated ground truth poses.
RpeResult computeRpe(const Trajectory& estimate, const Trajectory& ground_truth, int64_t delta_ns,
                     const AssociationParams& params = {});

/// Ground-truth pose at `stamp_ns` by interpolation between the two nearest
/// samples; false when the stamp is outside the trajectory or the bracketing
/// samples are more than max_gap_ns apart.
bool interpolatePose(const Trajectory& trajectory, int64_t stamp_ns, int64_t max_gap_ns, Eigen::Isometry3d& pose);

}  // namespace hxmap::alg
