#include "hxmap/eval/trajectory_metrics.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include <Eigen/SVD>

#include "hxmap/geometry/se3.hpp"

namespace hxmap::alg {

std::vector<std::pair<size_t, size_t>> associateStamps(const std::vector<int64_t>& a, const std::vector<int64_t>& b,
                                                       const AssociationParams& params) {
  // Candidate pairs within the window. b is searched through a sorted index so
  // the cost is O((n + m) log m + candidates), not O(n m).
  std::vector<size_t> order_b(b.size());
  std::iota(order_b.begin(), order_b.end(), 0);
  std::sort(order_b.begin(), order_b.end(), [&](size_t x, size_t y) { return b[x] < b[y]; });
  struct Candidate {
    int64_t diff;
    size_t i, j;
  };
  std::vector<Candidate> candidates;
  for (size_t i = 0; i < a.size(); ++i) {
    const int64_t lo = a[i] - params.max_difference_ns;
    auto it = std::lower_bound(order_b.begin(), order_b.end(), lo,
                               [&](size_t j, int64_t v) { return b[j] + params.offset_ns < v; });
    for (; it != order_b.end(); ++it) {
      const int64_t diff = std::llabs(a[i] - (b[*it] + params.offset_ns));
      if (b[*it] + params.offset_ns > a[i] + params.max_difference_ns) break;
      if (diff < params.max_difference_ns) candidates.push_back({diff, i, *it});
    }
  }
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Candidate& x, const Candidate& y) { return x.diff < y.diff; });
  std::vector<bool> used_a(a.size(), false), used_b(b.size(), false);
  std::vector<std::pair<size_t, size_t>> matches;
  for (const auto& c : candidates) {
    if (used_a[c.i] || used_b[c.j]) continue;
    used_a[c.i] = used_b[c.j] = true;
    matches.emplace_back(c.i, c.j);
  }
  std::sort(matches.begin(), matches.end());
  return matches;
}

Eigen::Isometry3d alignRigid(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst) {
  Eigen::Isometry3d T_dst_src = Eigen::Isometry3d::Identity();
  const size_t n = std::min(src.size(), dst.size());
  if (n == 0) return T_dst_src;
  Eigen::Vector3d mu_s = Eigen::Vector3d::Zero(), mu_d = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    mu_s += src[i];
    mu_d += dst[i];
  }
  mu_s /= static_cast<double>(n);
  mu_d /= static_cast<double>(n);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < n; ++i) cov += (dst[i] - mu_d) * (src[i] - mu_s).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d S = Eigen::Matrix3d::Identity();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0) S(2, 2) = -1;
  T_dst_src.linear() = svd.matrixU() * S * svd.matrixV().transpose();
  T_dst_src.translation() = mu_d - T_dst_src.linear() * mu_s;
  return T_dst_src;
}

namespace {
std::vector<int64_t> stampsOf(const Trajectory& t) {
  std::vector<int64_t> s;
  s.reserve(t.size());
  for (const auto& p : t) s.push_back(p.stamp_ns);
  return s;
}
}  // namespace

AteResult computeAte(const Trajectory& estimate, const Trajectory& ground_truth, const AssociationParams& params) {
  AteResult r;
  const auto matches = associateStamps(stampsOf(estimate), stampsOf(ground_truth), params);
  if (matches.size() < 3) return r;
  std::vector<Eigen::Vector3d> src, dst;
  for (const auto& [i, j] : matches) {
    src.push_back(estimate[i].T_world_cam.translation());
    dst.push_back(ground_truth[j].T_world_cam.translation());
  }
  r.T_gt_est = alignRigid(src, dst);
  std::vector<double> errors;
  double sum_sq = 0;
  for (size_t k = 0; k < src.size(); ++k) {
    const double e = (r.T_gt_est * src[k] - dst[k]).norm();
    errors.push_back(e);
    sum_sq += e * e;
  }
  r.pairs = errors.size();
  r.rmse_m = std::sqrt(sum_sq / static_cast<double>(r.pairs));
  r.mean_m = std::accumulate(errors.begin(), errors.end(), 0.0) / static_cast<double>(r.pairs);
  r.max_m = *std::max_element(errors.begin(), errors.end());
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  const size_t n = sorted.size();
  r.median_m = n % 2 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
  return r;
}

RpeResult computeRpe(const Trajectory& estimate, const Trajectory& ground_truth, int64_t delta_ns,
                     const AssociationParams& params) {
  RpeResult r;
  const auto matches = associateStamps(stampsOf(estimate), stampsOf(ground_truth), params);
  double sum_t = 0, sum_r = 0;
  size_t k2 = 0;
  for (size_t k = 0; k < matches.size(); ++k) {
    const int64_t target = estimate[matches[k].first].stamp_ns + delta_ns;
    k2 = std::max(k2, k + 1);
    while (k2 < matches.size() && estimate[matches[k2].first].stamp_ns < target) ++k2;
    if (k2 >= matches.size()) break;
    const auto& e0 = estimate[matches[k].first].T_world_cam;
    const auto& e1 = estimate[matches[k2].first].T_world_cam;
    const auto& g0 = ground_truth[matches[k].second].T_world_cam;
    const auto& g1 = ground_truth[matches[k2].second].T_world_cam;
    const Eigen::Isometry3d E = (g0.inverse() * g1).inverse() * (e0.inverse() * e1);
    sum_t += E.translation().squaredNorm();
    const double a = rotationAngle(E) * 180.0 / M_PI;
    sum_r += a * a;
    ++r.pairs;
  }
  if (r.pairs > 0) {
    r.trans_rmse_m = std::sqrt(sum_t / static_cast<double>(r.pairs));
    r.rot_rmse_deg = std::sqrt(sum_r / static_cast<double>(r.pairs));
  }
  return r;
}

bool interpolatePose(const Trajectory& trajectory, int64_t stamp_ns, int64_t max_gap_ns, Eigen::Isometry3d& pose) {
  if (trajectory.empty()) return false;
  auto it = std::lower_bound(trajectory.begin(), trajectory.end(), stamp_ns,
                             [](const StampedPose& p, int64_t s) { return p.stamp_ns < s; });
  if (it != trajectory.end() && it->stamp_ns == stamp_ns) {
    pose = it->T_world_cam;
    return true;
  }
  if (it == trajectory.begin() || it == trajectory.end()) return false;
  const auto& b = *it;
  const auto& a = *(it - 1);
  if (b.stamp_ns - a.stamp_ns > max_gap_ns) return false;
  const double t = static_cast<double>(stamp_ns - a.stamp_ns) / static_cast<double>(b.stamp_ns - a.stamp_ns);
  pose = interpolate(a.T_world_cam, b.T_world_cam, t);
  return true;
}

}  // namespace hxmap::alg
