#include "hxmap/posegraph/pose_graph.hpp"

#include <chrono>
#include <memory>

#include <ceres/ceres.h>
#include <ceres/manifold.h>

namespace hxmap::alg {

namespace {

// Whitened error of a relative pose: e = (2 vec(dq), dt) with
// dq = q_meas^-1 q_from^-1 q_to and dt = R_meas^T (R_from^T (t_to -
// t_from) - t_meas), then r = sqrt_information * e.
struct RelativePoseError {
  RelativePoseError(const Eigen::Isometry3d& T_meas, const Matrix6d& sqrt_information)
      : q_meas_inv(Eigen::Quaterniond(T_meas.linear()).conjugate()),
        t_meas(T_meas.translation()),
        sqrt_information(sqrt_information) {}

  template <typename S>
  bool operator()(const S* q_from_p, const S* t_from_p, const S* q_to_p, const S* t_to_p, S* residual_p) const {
    const Eigen::Map<const Eigen::Quaternion<S>> q_from(q_from_p), q_to(q_to_p);
    const Eigen::Map<const Eigen::Matrix<S, 3, 1>> t_from(t_from_p), t_to(t_to_p);
    const Eigen::Quaternion<S> q_from_inv = q_from.conjugate();
    const Eigen::Quaternion<S> q_est = q_from_inv * q_to;
    const Eigen::Matrix<S, 3, 1> t_est = q_from_inv * (t_to - t_from);
    const Eigen::Quaternion<S> q_meas_inv_s = q_meas_inv.cast<S>();
    const Eigen::Quaternion<S> dq = q_meas_inv_s * q_est;
    Eigen::Matrix<S, 6, 1> e;
    e.template head<3>() = S(2.0) * dq.vec();
    e.template tail<3>() = q_meas_inv_s * (t_est - t_meas.cast<S>());
    Eigen::Map<Eigen::Matrix<S, 6, 1>> residual(residual_p);
    residual = sqrt_information.cast<S>() * e;
    return true;
  }

  Eigen::Quaterniond q_meas_inv;
  Eigen::Vector3d t_meas;
  Matrix6d sqrt_information;
};

Matrix6d sqrtInformation(const Matrix6d& information) {
  // information = L L^T; the whitening matrix is L^T (upper).
  const Eigen::LLT<Matrix6d> llt(0.5 * (information + information.transpose()));
  if (llt.info() != Eigen::Success) return Matrix6d::Zero();
  return llt.matrixL().transpose();
}

struct NodeBlock {
  double q[4];  // x, y, z, w (Eigen's storage order)
  double t[3];
};

}  // namespace

Matrix6d isotropicInformation(double sigma_rotation_rad, double sigma_translation_m) {
  Matrix6d info = Matrix6d::Zero();
  info.diagonal().head<3>().setConstant(1.0 / (sigma_rotation_rad * sigma_rotation_rad));
  info.diagonal().tail<3>().setConstant(1.0 / (sigma_translation_m * sigma_translation_m));
  return info;
}

Matrix6d shapedInformation(const Matrix6d& registration, double sigma_rotation_rad, double sigma_translation_m,
                           double min_ratio) {
  Vector6d d;
  d << sigma_rotation_rad, sigma_rotation_rad, sigma_rotation_rad, sigma_translation_m, sigma_translation_m,
      sigma_translation_m;
  // In units of the isotropic sigmas, scaled so that the largest
  // eigenvalue is 1.
  const Matrix6d m = d.asDiagonal() * (0.5 * (registration + registration.transpose())) * d.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(m);
  const double top = eig.eigenvalues().maxCoeff();
  if (!registration.allFinite() || eig.info() != Eigen::Success || !(top > 0) || !(eig.eigenvalues().minCoeff() > 0)) {
    return isotropicInformation(sigma_rotation_rad, sigma_translation_m);
  }
  // Eigenvalues below min_ratio of the largest are raised to it.
  Vector6d lambda = eig.eigenvalues() / top;
  lambda = lambda.cwiseMax(min_ratio);
  const Matrix6d shaped = eig.eigenvectors() * lambda.asDiagonal() * eig.eigenvectors().transpose();
  const Vector6d inv_d = d.cwiseInverse();
  return inv_d.asDiagonal() * shaped * inv_d.asDiagonal();
}

void PoseGraph::setNode(uint32_t id, const Eigen::Isometry3d& T_world_node) { nodes_[id] = T_world_node; }

bool PoseGraph::addFactor(const PoseGraphFactor& factor) {
  if (!hasNode(factor.from) || !hasNode(factor.to) || factor.from == factor.to) return false;
  if (!factor.T_from_to.matrix().allFinite() || !factor.information.allFinite()) return false;
  factors_.push_back(factor);
  return true;
}

double PoseGraph::whitenedError(const PoseGraphFactor& f) const {
  const RelativePoseError err(f.T_from_to, sqrtInformation(f.information));
  const Eigen::Quaterniond qa(node(f.from).linear()), qb(node(f.to).linear());
  const Eigen::Vector3d ta = node(f.from).translation(), tb = node(f.to).translation();
  Vector6d r;
  err(qa.coeffs().data(), ta.data(), qb.coeffs().data(), tb.data(), r.data());
  return r.norm();
}

PoseGraphReport PoseGraph::addLoop(const PoseGraphFactor& factor, uint32_t fixed, double gate, int max_iterations) {
  const std::map<uint32_t, Eigen::Isometry3d> nodes_before = nodes_;
  PoseGraphFactor f = factor;
  f.loop = true;
  PoseGraphReport report;
  if (!addFactor(f)) {
    report.failure = "a loop factor between unknown nodes or with non-finite values";
    return report;
  }
  report = optimize(fixed, max_iterations);
  if (!report.failure.empty() || report.max_whitened_error > gate) {
    report.refused = true;
    factors_.pop_back();
    nodes_ = nodes_before;
  }
  return report;
}

PoseGraphReport PoseGraph::optimize(uint32_t fixed, int max_iterations) {
  PoseGraphReport report;
  const auto t0 = std::chrono::steady_clock::now();
  if (!hasNode(fixed)) {
    report.failure = "the fixed node " + std::to_string(fixed) + " is not in the graph";
    return report;
  }
  std::map<uint32_t, NodeBlock> blocks;
  for (const auto& [id, T_world_kf] : nodes_) {
    NodeBlock b;
    const Eigen::Quaterniond q(T_world_kf.linear());
    for (int k = 0; k < 4; ++k) b.q[k] = q.coeffs()[k];
    for (int k = 0; k < 3; ++k) b.t[k] = T_world_kf.translation()[k];
    blocks[id] = b;
  }
  ceres::Problem::Options options;
  options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(options);
  ceres::EigenQuaternionManifold quaternion_manifold;
  for (const PoseGraphFactor& f : factors_) {
    auto* cost = new ceres::AutoDiffCostFunction<RelativePoseError, 6, 4, 3, 4, 3>(
        new RelativePoseError(f.T_from_to, sqrtInformation(f.information)));
    NodeBlock& a = blocks[f.from];
    NodeBlock& b = blocks[f.to];
    problem.AddResidualBlock(cost, nullptr, a.q, a.t, b.q, b.t);
  }
  for (auto& [id, b] : blocks) {
    if (!problem.HasParameterBlock(b.q)) continue;
    problem.SetManifold(b.q, &quaternion_manifold);
    if (id == fixed || isFixed(id)) {
      problem.SetParameterBlockConstant(b.q);
      problem.SetParameterBlockConstant(b.t);
    }
  }
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver.max_num_iterations = std::max(1, max_iterations);
  solver.num_threads = 1;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  report.cost_before = summary.initial_cost;
  report.cost_after = summary.final_cost;
  report.iterations = static_cast<int>(summary.iterations.size());
  if (!summary.IsSolutionUsable()) {
    report.failure = summary.message;
    return report;
  }
  for (auto& [id, b] : blocks) {
    Eigen::Quaterniond q(b.q[3], b.q[0], b.q[1], b.q[2]);
    q.normalize();
    Eigen::Isometry3d T_world_kf = Eigen::Isometry3d::Identity();
    T_world_kf.linear() = q.toRotationMatrix();
    T_world_kf.translation() = Eigen::Vector3d(b.t[0], b.t[1], b.t[2]);
    nodes_[id] = T_world_kf;
  }
  for (const PoseGraphFactor& f : factors_) report.max_whitened_error = std::max(report.max_whitened_error, whitenedError(f));
  report.solve_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return report;
}

}  // namespace hxmap::alg
