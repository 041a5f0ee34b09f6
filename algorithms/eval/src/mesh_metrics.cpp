#include "hxmap/eval/mesh_metrics.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "hxmap/eval/triangle_bvh.hpp"

namespace hxmap::alg {

std::vector<Eigen::Vector3f> sampleSurface(const TriangleMesh& mesh, int samples, uint64_t seed,
                                           std::vector<Eigen::Vector3f>* normals) {
  std::vector<Eigen::Vector3f> points;
  if (normals != nullptr) normals->clear();
  if (mesh.triangles.empty() || samples <= 0) return points;
  std::vector<double> cdf(mesh.triangles.size());
  double total = 0;
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    const Eigen::Vector3d a = mesh.vertices[t[0]].cast<double>(), b = mesh.vertices[t[1]].cast<double>(),
                          c = mesh.vertices[t[2]].cast<double>();
    total += 0.5 * (b - a).cross(c - a).norm();
    cdf[i] = total;
  }
  if (!(total > 0)) return points;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  points.reserve(samples);
  for (int s = 0; s < samples; ++s) {
    const double r = uni(rng) * total;
    const size_t i = std::min<size_t>(std::lower_bound(cdf.begin(), cdf.end(), r) - cdf.begin(), cdf.size() - 1);
    const auto& t = mesh.triangles[i];
    double u = uni(rng), v = uni(rng);
    if (u + v > 1) {
      u = 1 - u;
      v = 1 - v;
    }
    const Eigen::Vector3d a = mesh.vertices[t[0]].cast<double>(), b = mesh.vertices[t[1]].cast<double>(),
                          c = mesh.vertices[t[2]].cast<double>();
    points.push_back((a + u * (b - a) + v * (c - a)).cast<float>());
    if (normals != nullptr) normals->push_back((b - a).cross(c - a).normalized().cast<float>());
  }
  return points;
}

std::vector<bool> visibleFromAny(const std::vector<Eigen::Vector3f>& points, const TriangleMesh& mesh,
                                 const PinholeCamera& camera, const Trajectory& poses, double max_depth_m,
                                 const ParallelFor& parallel) {
  return observedFromAny(points, {}, mesh, ObservedBy{camera, poses, max_depth_m, 0.0}, parallel);
}

std::vector<bool> observedFromAny(const std::vector<Eigen::Vector3f>& points,
                                  const std::vector<Eigen::Vector3f>& normals, const TriangleMesh& mesh,
                                  const ObservedBy& by, const ParallelFor& parallel) {
  const PinholeCamera& camera = by.camera;
  const Trajectory& poses = by.poses;
  const double max_depth_m = by.max_depth_m;
  const bool incidence = by.min_abs_cos > 0 && normals.size() == points.size();
  const float min_abs_cos = static_cast<float>(by.min_abs_cos);
  const TriangleBvh bvh(mesh);
  // At most 60 poses, evenly spread: neighbouring frames see nearly the same surface.
  std::vector<Eigen::Isometry3f> T_cam_world;
  const size_t stride = std::max<size_t>(1, poses.size() / 60);
  for (size_t i = 0; i < poses.size(); i += stride) T_cam_world.push_back(poses[i].T_world_cam.inverse().cast<float>());
  std::vector<char> visible(points.size(), 0);
  parallel(points.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      for (const auto& T : T_cam_world) {
        const Eigen::Vector3f p_cam = T * points[k];
        if (p_cam.z() < 0.05f || p_cam.z() > max_depth_m) continue;
        const Eigen::Vector2f uv = camera.project(p_cam);
        if (!camera.inside(uv.x(), uv.y())) continue;
        const Eigen::Vector3f origin = T.inverse().translation();
        const Eigen::Vector3f d = points[k] - origin;
        const float dist = d.norm();
        if (incidence && std::abs(normals[k].dot(d)) < min_abs_cos * dist) continue;
        // Visible when nothing is hit before the point (1 cm slack for the
        // point's own triangle and its neighbours).
        if (bvh.raycast(origin, d / dist, 0.0f, dist - 0.01f) >= dist - 0.01f) {
          visible[k] = 1;
          break;
        }
      }
    }
  });
  return {visible.begin(), visible.end()};
}

std::vector<Eigen::Vector3f> keepObserved(const std::vector<Eigen::Vector3f>& points,
                                          const std::vector<Eigen::Vector3f>& normals, const TriangleMesh& mesh,
                                          const ObservedBy& by, const ParallelFor& parallel) {
  const auto observed = observedFromAny(points, normals, mesh, by, parallel);
  std::vector<Eigen::Vector3f> kept;
  for (size_t k = 0; k < points.size(); ++k) {
    if (observed[k]) kept.push_back(points[k]);
  }
  return kept;
}

namespace {

template <typename DistanceFn>
std::vector<float> distances(const std::vector<Eigen::Vector3f>& points, DistanceFn&& fn, const ParallelFor& parallel) {
  std::vector<float> d(points.size());
  parallel(points.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) d[k] = fn(points[k]);
  });
  return d;
}

double meanOf(const std::vector<float>& d) {
  double s = 0;
  for (float x : d) s += x;
  return d.empty() ? 0.0 : s / static_cast<double>(d.size());
}

double shareBelow(const std::vector<float>& d, double t) {
  size_t n = 0;
  for (float x : d) n += x < t;
  return d.empty() ? 0.0 : static_cast<double>(n) / static_cast<double>(d.size());
}

double f1(double p, double r) { return p + r > 0 ? 2 * p * r / (p + r) : 0.0; }

MeshScores score(const std::vector<float>& rec_to_gt, const std::vector<float>& gt_to_rec,
                 const MeshMetricsParams& pm) {
  MeshScores s;
  s.accuracy_cm = 100.0 * meanOf(rec_to_gt);
  s.completion_cm = 100.0 * meanOf(gt_to_rec);
  s.precision_fine = shareBelow(rec_to_gt, pm.threshold_fine_m);
  s.recall_fine = shareBelow(gt_to_rec, pm.threshold_fine_m);
  s.f1_fine = f1(s.precision_fine, s.recall_fine);
  s.precision_coarse = shareBelow(rec_to_gt, pm.threshold_coarse_m);
  s.recall_coarse = shareBelow(gt_to_rec, pm.threshold_coarse_m);
  s.f1_coarse = f1(s.precision_coarse, s.recall_coarse);
  s.completion_ratio_coarse = s.recall_coarse;
  return s;
}

}  // namespace

MeshMetrics computeMeshMetrics(const TriangleMesh& reconstruction, const TriangleMesh& ground_truth,
                               const MeshMetricsParams& params, const ObservedBy* gt_observed,
                               const ParallelFor& parallel) {
  MeshMetrics m;
  const auto rec_pts = sampleSurface(reconstruction, params.samples, params.seed);
  std::vector<Eigen::Vector3f> gt_normals;
  auto gt_pts = sampleSurface(ground_truth, params.samples, params.seed + 1, &gt_normals);
  if (gt_observed != nullptr) gt_pts = keepObserved(gt_pts, gt_normals, ground_truth, *gt_observed, parallel);
  m.reconstruction_samples = rec_pts.size();
  m.ground_truth_samples = gt_pts.size();
  const TriangleBvh rec_bvh(reconstruction), gt_bvh(ground_truth);
  const auto rec_to_gt = distances(
      rec_pts, [&](const Eigen::Vector3f& p) { return gt_bvh.distance(p); }, parallel);
  const auto gt_to_rec = distances(
      gt_pts, [&](const Eigen::Vector3f& p) { return rec_bvh.distance(p); }, parallel);
  m.point_to_surface = score(rec_to_gt, gt_to_rec, params);
  if (params.point_to_point) {
    const PointKdTree rec_tree(rec_pts), gt_tree(gt_pts);
    const auto r2g = distances(
        rec_pts, [&](const Eigen::Vector3f& p) { return gt_tree.distance(p); }, parallel);
    const auto g2r = distances(
        gt_pts, [&](const Eigen::Vector3f& p) { return rec_tree.distance(p); }, parallel);
    m.point_to_point = score(r2g, g2r, params);
  }
  return m;
}

}  // namespace hxmap::alg
