// Mesh accuracy and completeness against a ground-truth mesh.
//
// Points are sampled uniformly by area on each mesh and each point's distance
// is measured to the other mesh's *surface* (nearest triangle). The
// point-to-sampled-point variant that many papers publish is computed too and
// labelled as such: with ~200k samples on a room the samples are ~1 cm apart,
// which caps even a perfect reconstruction's F1 at 1 cm far below 100%.
#pragma once

#include <cstdint>
#include <vector>

#include "hxmap/core/frame.hpp"
#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/camera.hpp"
#include "hxmap/geometry/mesh.hpp"

namespace hxmap::alg {

struct MeshMetricsParams {
  int samples = 200'000;  ///< per mesh
  uint64_t seed = 1;      ///< sampling is deterministic from it
  double threshold_fine_m = 0.01;
  double threshold_coarse_m = 0.05;
  bool point_to_point = true;  ///< also compute the sampled-point variant
};

struct MeshScores {
  double accuracy_cm = 0;                                         ///< mean distance reconstruction -> ground truth
  double completion_cm = 0;                                       ///< mean distance ground truth -> reconstruction
  double precision_fine = 0, recall_fine = 0, f1_fine = 0;        ///< at threshold_fine_m, in [0, 1]
  double precision_coarse = 0, recall_coarse = 0, f1_coarse = 0;  ///< at threshold_coarse_m
  double completion_ratio_coarse = 0;                             ///< share of ground truth within threshold_coarse_m
};

struct MeshMetrics {
  MeshScores point_to_surface;
  MeshScores point_to_point;  ///< only when params.point_to_point
  size_t reconstruction_samples = 0;
  size_t ground_truth_samples = 0;  ///< after removing unobserved surface
};

/// `samples` points uniformly by area; deterministic for a seed. `normals`,
/// when given, receives each point's triangle normal (unit length).
std::vector<Eigen::Vector3f> sampleSurface(const TriangleMesh& mesh, int samples, uint64_t seed,
                                           std::vector<Eigen::Vector3f>* normals = nullptr);

/// The views a sensor observed a scene from, and what it can measure.
struct ObservedBy {
  PinholeCamera camera;
  Trajectory poses;
  double max_depth_m = 10.0;
  /// The sensor returns no depth where |cos(incidence)| is below this: a
  /// surface seen only at grazing angles was never measured (0: any angle).
  double min_abs_cos = 0.0;
};

/// Which points are visible from at least one of the poses: inside the image,
/// in front of the camera, within max_depth_m, and not occluded by `mesh`;
/// with `normals` (one per point), also not seen at an incidence whose
/// |cos| is below by.min_abs_cos.
std::vector<bool> observedFromAny(const std::vector<Eigen::Vector3f>& points,
                                  const std::vector<Eigen::Vector3f>& normals, const TriangleMesh& mesh,
                                  const ObservedBy& by, const ParallelFor& parallel = serialFor);

/// The points observedFromAny keeps, in order.
std::vector<Eigen::Vector3f> keepObserved(const std::vector<Eigen::Vector3f>& points,
                                          const std::vector<Eigen::Vector3f>& normals, const TriangleMesh& mesh,
                                          const ObservedBy& by, const ParallelFor& parallel = serialFor);

/// observedFromAny at any incidence.
std::vector<bool> visibleFromAny(const std::vector<Eigen::Vector3f>& points, const TriangleMesh& mesh,
                                 const PinholeCamera& camera, const Trajectory& poses, double max_depth_m = 10.0,
                                 const ParallelFor& parallel = serialFor);

/// Scores `reconstruction` against `ground_truth`. `gt_observed`, when given
/// (camera + poses), removes ground-truth surface those poses never observed
/// from completion and recall.
MeshMetrics computeMeshMetrics(const TriangleMesh& reconstruction, const TriangleMesh& ground_truth,
                               const MeshMetricsParams& params, const ObservedBy* gt_observed = nullptr,
                               const ParallelFor& parallel = serialFor);

}  // namespace hxmap::alg
