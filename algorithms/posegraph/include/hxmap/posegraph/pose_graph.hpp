// A pose graph over keyframes: nodes are T_world_kf, factors relative poses
// between two keyframes (tracking's odometry from one keyframe to the next,
// and loop closures), each with a 6x6 information matrix in the order
// (rotation rad, translation m) of a right perturbation of the `to` pose
// seen from `from`. Optimized with Ceres (Levenberg-Marquardt, sparse
// Cholesky). A loop closure is accepted only when the graph can take it:
// after the solve with it, no factor's whitened error may exceed a
// chi-square gate; otherwise it is refused and the graph left as it was,
// so that one wrong closure cannot pull the whole graph.
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/geometry/se3.hpp"

namespace hxmap::alg {

struct PoseGraphFactor {
  uint32_t from = 0, to = 0;
  Eigen::Isometry3d T_from_to = Eigen::Isometry3d::Identity();  ///< measured
  Matrix6d information = Matrix6d::Identity();
  bool loop = false;  ///< a loop closure (robust loss) rather than odometry
};

struct PoseGraphReport {
  double cost_before = 0, cost_after = 0;  ///< 0.5 * sum of squared whitened residuals
  int iterations = 0;  ///< of the last solve
  double solve_ms = 0;
  double max_whitened_error = 0;  ///< over all factors, at the solution
  bool refused = false;           ///< addLoop: the closure did not fit (graph unchanged)
  std::string failure;  ///< empty when the solve ran
};

/// Information of a relative pose measured with standard deviations
/// sigma_rotation_rad and sigma_translation_m per axis.
Matrix6d isotropicInformation(double sigma_rotation_rad, double sigma_translation_m);

/// The information of a registration (e.g. ICP's J^T W J, whose scale is
/// far overconfident) reshaped for a factor: its best-constrained direction
/// gets the isotropic sigmas, weaker directions proportionally larger ones
/// (a view of one wall constrains little along it), down to `min_ratio`
/// of the best one's information. Falls back to the isotropic information
/// when `registration` is not positive definite.
Matrix6d shapedInformation(const Matrix6d& registration, double sigma_rotation_rad, double sigma_translation_m,
                           double min_ratio = 0.0);

class PoseGraph {
 public:
  /// Adds or moves a node.
  void setNode(uint32_t id, const Eigen::Isometry3d& T_world_node);
  /// Moves nodes back (e.g. to before a solve whose result is not used).
  void setNodes(const std::map<uint32_t, Eigen::Isometry3d>& nodes) {
    for (const auto& [id, T] : nodes) setNode(id, T);
  }
  /// Keeps a node where it is in every solve (e.g. a saved map's
  /// keyframes, which a run that continues the map must not move).
  void fixNode(uint32_t id) { fixed_.insert(id); }
  bool isFixed(uint32_t id) const { return fixed_.count(id) != 0; }
  /// A factor between two nodes that exist (false otherwise).
  bool addFactor(const PoseGraphFactor& factor);
  /// Optimizes every node but `fixed` (the gauge) and those fixNode() kept.
  PoseGraphReport optimize(uint32_t fixed, int max_iterations = 50);
  /// Adds a loop factor and optimizes; when afterwards any factor's
  /// whitened error exceeds `gate` (the square root of a chi-square
  /// quantile with 6 degrees of freedom), the factor is refused and nodes
  /// and factors are as before the call.
  PoseGraphReport addLoop(const PoseGraphFactor& factor, uint32_t fixed, double gate, int max_iterations = 50);
  /// Whitened residual norm of a factor at the current nodes.
  double whitenedError(const PoseGraphFactor& factor) const;

  const std::map<uint32_t, Eigen::Isometry3d>& nodes() const { return nodes_; }
  const std::vector<PoseGraphFactor>& factors() const { return factors_; }
  bool hasNode(uint32_t id) const { return nodes_.count(id) != 0; }
  const Eigen::Isometry3d& node(uint32_t id) const { return nodes_.at(id); }

 private:

  std::map<uint32_t, Eigen::Isometry3d> nodes_;
  std::vector<PoseGraphFactor> factors_;
  std::set<uint32_t> fixed_;
};

}  // namespace hxmap::alg
