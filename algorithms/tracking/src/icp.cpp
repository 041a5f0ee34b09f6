#include "hxmap/tracking/icp.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "hxmap/tracking/icp_kernels.hpp"
#include "hxmap/tracking/normal_equations.hpp"

namespace hxmap::alg {

namespace {

struct Accumulation {
  NormalEquations eq;
  double sq_sum = 0;
  double abs_sum = 0;  ///< |r| clipped at 3 Huber thresholds (a robust spread)
  int inliers = 0;
  int consistent = 0;              ///< inliers within consistent_sigmas * sigma(z) of the model's plane
  double photometric_abs_sum = 0;  ///< the same for the photometric residuals
  int photometric_n = 0;
  void merge(const Accumulation& o) {
    eq.merge(o.eq);
    sq_sum += o.sq_sum;
    abs_sum += o.abs_sum;
    inliers += o.inliers;
    consistent += o.consistent;
    photometric_abs_sum += o.photometric_abs_sum;
    photometric_n += o.photometric_n;
  }
};

// Rows of an image of `rows` rows split into kChunks fixed bands (multiples
// of `stride`), accumulated in parallel and summed in band order: the
// result does not depend on the number of threads.
constexpr int kChunks = 8;

template <typename Body>  // body(band, v_begin, v_end)
void forBands(int rows, int stride, const ParallelFor& parallel, const Body& body) {
  const int steps = (rows + stride - 1) / stride;
  parallel(kChunks, [&](size_t c0, size_t c1) {
    for (size_t c = c0; c < c1; ++c) {
      const int s0 = static_cast<int>(c) * steps / kChunks, s1 = (static_cast<int>(c) + 1) * steps / kChunks;
      body(static_cast<int>(c), s0 * stride, std::min(rows, s1 * stride));
    }
  });
}

// body(band, acc) for each band, in parallel, summed in band order.
template <typename Body>
void accumulateBands(const ParallelFor& parallel, Accumulation& acc, const Body& body) {
  std::array<Accumulation, kChunks> part;
  parallel(kChunks, [&](size_t c0, size_t c1) {
    for (size_t c = c0; c < c1; ++c) body(static_cast<int>(c), part[c]);
  });
  for (const auto& p : part) acc.merge(p);
}

// "37 %" (algorithms/ has no fmt: it builds with OpenCV and Eigen alone).
std::string percent(double share) { return std::to_string(std::lround(100 * share)) + " %"; }

// The frame pixels of the point-to-plane term, one array per coordinate:
// camera-frame point, normal and confidence.
struct FramePoints {
  std::vector<float> px, py, pz, nx, ny, nz, conf;
  int size() const { return static_cast<int>(px.size()); }
  void clear() {
    for (auto* c : {&px, &py, &pz, &nx, &ny, &nz, &conf}) c->clear();
  }
  void push(const cv::Vec3f& p, const cv::Vec3f& n, float c) {
    px.push_back(p[0]);
    py.push_back(p[1]);
    pz.push_back(p[2]);
    nx.push_back(n[0]);
    ny.push_back(n[1]);
    nz.push_back(n[2]);
    conf.push_back(c);
  }
};

// The pixels of rows [v_begin, v_end) at `stride` with depth, a normal and
// confidence, gathered once per level and frame (as the photometric
// reference points are).
void gatherFrame(const FrameLevel& level, int stride, int v_begin, int v_end, FramePoints& out) {
  out.clear();
  for (int v = v_begin; v < v_end; v += stride) {
    const auto* vrow = level.vertex.ptr<cv::Vec3f>(v);
    const auto* nrow = level.normal.ptr<cv::Vec3f>(v);
    const float* crow = level.confidence.ptr<float>(v);
    for (int u = 0; u < level.vertex.cols; u += stride) {
      const cv::Vec3f& pc = vrow[u];
      if (pc[2] <= 0 || crow[u] <= 0) continue;
      const cv::Vec3f& nc = nrow[u];
      if (nc[0] == 0 && nc[1] == 0 && nc[2] == 0) continue;
      out.push(pc, nc, crow[u]);
    }
  }
}

using FrameBands = std::array<FramePoints, kChunks>;

FrameBands gatherFrameBands(const FrameLevel& level, int stride, const ParallelFor& parallel) {
  FrameBands out;
  forBands(level.vertex.rows, stride, parallel,
           [&](int c, int v0, int v1) { gatherFrame(level, stride, v0, v1, out[c]); });
  return out;
}

void accumulate(const FramePoints& points, const ModelView& model, const Eigen::Isometry3f& T_world_cam,
                const TrackingParams& params, Accumulation& acc) {
  const RigidF Tw(T_world_cam), T_ref(model.T_world_cam.inverse() * T_world_cam);
  const float max_d2 = static_cast<float>(params.max_correspondence_distance_m * params.max_correspondence_distance_m);
  const float cos_max = static_cast<float>(std::cos(params.max_normal_angle_deg * M_PI / 180.0));
  const float huber = static_cast<float>(params.huber_delta_m);
  const PinholeCamera& mc = model.camera;
  const float k[4] = {static_cast<float>(mc.fx), static_cast<float>(mc.fy), static_cast<float>(mc.cx),
                      static_cast<float>(mc.cy)};
  const float sig_a = static_cast<float>(params.noise_sigma_a_m),
              sig_b = static_cast<float>(params.noise_sigma_b_per_m);
  const float k_sig = static_cast<float>(params.consistent_sigmas);
  const auto* normals = model.normal_world.ptr<cv::Vec3f>(0);  // continuous (created whole)
  const auto* vertices = model.vertex_world.ptr<cv::Vec3f>(0);
  GeometricProjection proj;
  GeometricRows rows;
  for (int b = 0; b < points.size(); b += kPointBatch) {
    const int m = std::min(kPointBatch, points.size() - b);
    projectFramePoints(points.px.data() + b, points.py.data() + b, points.pz.data() + b, points.nx.data() + b,
                       points.ny.data() + b, points.nz.data() + b, m, Tw, T_ref, k, mc.width, mc.height, proj);
    int n = 0;
    // DESIGN: no branch per point. Every point is read (a point outside
    // the image reads pixel 0) and written at the next free row, which it
    // keeps only if it passes: the tests failed about half the time in no
    // pattern a branch predictor could follow.
    for (int i = 0; i < m; ++i) {
      const int pixel = proj.ok[i] ? static_cast<int>(proj.v[i]) * mc.width + static_cast<int>(proj.u[i]) : 0;
      const cv::Vec3f& qn = normals[pixel];
      const cv::Vec3f& qv = vertices[pixel];
      const float dx = proj.x[0][i] - qv[0], dy = proj.x[1][i] - qv[1], dz = proj.x[2][i] - qv[2];
      const float cos_n = proj.n[0][i] * qn[0] + proj.n[1][i] * qn[1] + proj.n[2][i] * qn[2];
      const bool has_normal =
          (static_cast<int>(qn[0] != 0) | static_cast<int>(qn[1] != 0) | static_cast<int>(qn[2] != 0)) != 0;
      const bool keep = (proj.ok[i] != 0) & has_normal & (dx * dx + dy * dy + dz * dz <= max_d2) & (cos_n >= cos_max);
      for (int j = 0; j < 3; ++j) {
        rows.x[j][n] = proj.x[j][i];
        rows.q[j][n] = qv[j];
        rows.n[j][n] = qn[j];
      }
      rows.w[n] = points.conf[b + i] * cos_n;  // w(p): confidence and normal consistency
      rows.z[n] = points.pz[b + i];
      n += keep;
    }
    geometricRows(n, huber, rows);
    for (int i = 0; i < n; ++i) {
      const float r = rows.r[i], ar = std::abs(r);
      acc.sq_sum += static_cast<double>(r) * r;
      acc.abs_sum += std::min(ar, 3.0f * huber);
      const float dz = rows.z[i] - 0.4f;
      acc.consistent += ar <= k_sig * (sig_a + sig_b * dz * dz);
    }
    float* const J[6] = {rows.J[0], rows.J[1], rows.J[2], rows.J[3], rows.J[4], rows.J[5]};
    acc.eq.addColumns(J, rows.w, rows.r, n);
    acc.inliers += n;
  }
}

// Bilinear (I, dI/du, dI/dv) from an interleaved CV_32FC3 image; u, v >= 0
// and at least one pixel inside the right and bottom borders.
inline Eigen::Vector3f bilinear3(const cv::Mat& img, float u, float v) {
  const int u0 = static_cast<int>(u), v0 = static_cast<int>(v);
  const float a = u - static_cast<float>(u0), b = v - static_cast<float>(v0);
  const float* r0 = img.ptr<float>(v0) + 3 * u0;
  const float* r1 = img.ptr<float>(v0 + 1) + 3 * u0;
  const float w00 = (1 - a) * (1 - b), w01 = a * (1 - b), w10 = (1 - a) * b, w11 = a * b;
  return {w00 * r0[0] + w01 * r0[3] + w10 * r1[0] + w11 * r1[3], w00 * r0[1] + w01 * r0[4] + w10 * r1[1] + w11 * r1[4],
          w00 * r0[2] + w01 * r0[5] + w10 * r1[2] + w11 * r1[5]};
}

// The reference pixels of the photometric term, one array per coordinate:
// point in the world, intensity and confidence.
struct RefPoints {
  std::vector<float> x, y, z, intensity, conf;
  int size() const { return static_cast<int>(x.size()); }
  void clear() {
    for (auto* c : {&x, &y, &z, &intensity, &conf}) c->clear();
  }
};

// The reference pixels of rows [v_begin, v_end) at `stride`, with depth,
// confidence (from `ref_conf`, which may be `conf_shift` levels coarser)
// and an intensity gradient of their own not far below the one the warped
// pixel must have. DESIGN: gathered once per level and frame rather than in
// every Gauss-Newton iteration, so that an iteration reads packed arrays
// and transforms each point once. Half of the points that reach the
// gradient test in the current image fail it; the ones whose own gradient
// is well below the threshold (photometric_reference_gradient_ratio) are
// left out here.
void gatherReference(const FrameLevel& ref, const cv::Mat& ref_conf, int conf_shift,
                     const Eigen::Isometry3f& T_world_ref, const TrackingParams& params, int stride, int v_begin,
                     int v_end, RefPoints& out) {
  out.clear();
  const float rfx = static_cast<float>(1.0 / ref.camera.fx), rfy = static_cast<float>(1.0 / ref.camera.fy);
  const float rcx = static_cast<float>(ref.camera.cx), rcy = static_cast<float>(ref.camera.cy);
  const int conf_cols = ref_conf.cols;
  const float gmin_ref =
      static_cast<float>(params.photometric_reference_gradient_ratio * params.photometric_min_gradient);
  const float gmin2_ref = gmin_ref * gmin_ref;
  for (int v = v_begin; v < v_end; v += stride) {
    const float* drow = ref.depth.ptr<float>(v);
    const float* irow = ref.intensity.ptr<float>(v);
    const int cv_row = std::min(v >> conf_shift, ref_conf.rows - 1);
    const float* crow = ref_conf.ptr<float>(cv_row);
    const auto* grow = ref.intensity_grad.ptr<cv::Vec3f>(v);
    for (int u = 0; u < ref.depth.cols; u += stride) {
      const float z = drow[u];
      const float conf = crow[std::min(u >> conf_shift, conf_cols - 1)];
      if (!(z > 0) || conf <= 0) continue;
      const cv::Vec3f& gr = grow[u];
      if (gr[1] * gr[1] + gr[2] * gr[2] < gmin2_ref) continue;
      const Eigen::Vector3f p_ref((static_cast<float>(u) - rcx) * rfx * z, (static_cast<float>(v) - rcy) * rfy * z, z);
      const Eigen::Vector3f y = T_world_ref * p_ref;
      out.x.push_back(y.x());
      out.y.push_back(y.y());
      out.z.push_back(y.z());
      out.intensity.push_back(irow[u]);
      out.conf.push_back(conf);
    }
  }
}

// Photometric residuals r = I_cur(pi(T^-1 y)) - I_ref of reference points y
// in the world, added to acc.
void accumulatePhotometric(const FrameLevel& cur, const RefPoints& points, const Eigen::Isometry3f& T_world_cam,
                           const TrackingParams& params, Accumulation& acc) {
  const RigidF T_cur_world(T_world_cam.inverse());
  float R[9];
  for (int i = 0; i < 9; ++i) R[i] = T_world_cam.linear()(i / 3, i % 3);
  const float fx = static_cast<float>(cur.camera.fx), fy = static_cast<float>(cur.camera.fy);
  const float k[4] = {fx, fy, static_cast<float>(cur.camera.cx), static_cast<float>(cur.camera.cy)};
  const float scale = static_cast<float>(params.photometric_scale_m);
  const float huber = static_cast<float>(params.photometric_huber);
  const float gmin2 = static_cast<float>(params.photometric_min_gradient * params.photometric_min_gradient);
  const float W = static_cast<float>(cur.intensity.cols - 2), H = static_cast<float>(cur.intensity.rows - 2);
  PhotometricProjection proj;
  PhotometricRows rows;
  for (int b = 0; b < points.size(); b += kPointBatch) {
    const int m = std::min(kPointBatch, points.size() - b);
    projectRefPoints(points.x.data() + b, points.y.data() + b, points.z.data() + b, m, T_cur_world, k, W, H, proj);
    int n = 0;
    for (int i = 0; i < m; ++i) {  // no branch per point, as in accumulate()
      const bool ok = proj.ok[i] != 0;
      const float uu = ok ? proj.u[i] : 0.0f, vv = ok ? proj.v[i] : 0.0f, pz = proj.p[2][i];
      // Occlusion: the current depth there must agree with the warped point.
      const float zc = cur.depth.ptr<float>(static_cast<int>(vv + 0.5f))[static_cast<int>(uu + 0.5f)];
      const Eigen::Vector3f ig = bilinear3(cur.intensity_grad, uu, vv);
      const float gx = ig.y(), gy = ig.z();
      const bool keep = ok & (zc > 0.0f) & (std::abs(zc - pz) <= 0.03f + 0.02f * pz) & (gx * gx + gy * gy >= gmin2);
      rows.gx[n] = gx;
      rows.gy[n] = gy;
      rows.r[n] = ig.x() - points.intensity[b + i];
      rows.p[0][n] = proj.p[0][i];
      rows.p[1][n] = proj.p[1][i];
      rows.inv_z[n] = proj.inv_z[i];
      rows.y[0][n] = points.x[b + i];
      rows.y[1][n] = points.y[b + i];
      rows.y[2][n] = points.z[b + i];
      rows.w[n] = points.conf[b + i];
      n += keep;
    }
    photometricRows(n, R, fx, fy, scale, huber, rows);
    for (int i = 0; i < n; ++i) acc.photometric_abs_sum += rows.clipped[i];
    float* const J[6] = {rows.J[0], rows.J[1], rows.J[2], rows.J[3], rows.J[4], rows.J[5]};
    acc.eq.addColumns(J, rows.w, rows.r, n);
    acc.photometric_n += n;
  }
}

}  // namespace

IcpResult trackPointToPlane(const PreprocessedFrame& frame, const std::vector<ModelView>& model,
                            const Eigen::Isometry3d& T_init, const TrackingParams& params,
                            const PhotometricReference& reference, const ParallelFor& parallel) {
  IcpResult result;
  result.T_world_cam = T_init;
  if (model.empty() || frame.levels.empty()) {
    result.failure = "no model or no frame";
    return result;
  }
  const int levels = static_cast<int>(std::min(model.size(), frame.levels.size()));
  // Tracking runs from the coarsest level down to the frame's finest
  // preprocessed one; pixel counts below are at that level.
  const int finest = std::clamp(frame.finest, 0, levels - 1);
  result.model_pixels = model[finest].valid_pixels;
  const int iterations[3] = {params.iterations_finest, params.iterations_middle, params.iterations_coarsest};
  Eigen::Isometry3d T_world_cam = T_init;
  const bool use_photometric =
      reference.frame != nullptr && params.photometric_scale_m > 0 && frame.has_color && reference.frame->has_color;
  Accumulation last;  // the finest level's last point-to-plane evaluation
  bool have_last = false;
  double photometric_abs_sum = 0;  // and of its photometric terms
  int photometric_n = 0;
  for (int l = levels - 1; l >= finest; --l) {
    const int iters = iterations[std::min(l - finest, 2)];
    const int stride = l == finest ? params.icp_stride_finest : 1;
    const int photometric_stride = l == finest ? std::max(1, params.photometric_stride_finest) : 1;
    // At the finest level, intensity at full resolution where the frames
    // have it (finer texture than the geometry's level).
    const int pl = l == finest && !frame.levels[0].intensity.empty() && use_photometric &&
                           !reference.frame->levels[0].intensity.empty()
                       ? 0
                       : l;
    const bool photometric = use_photometric && static_cast<size_t>(l) < reference.frame->levels.size();
    const FrameBands frame_points = gatherFrameBands(frame.levels[l], stride, parallel);
    std::array<RefPoints, kChunks> ref_points;
    if (photometric) {
      const FrameLevel& ref = reference.frame->levels[pl];
      const Eigen::Isometry3f T_world_ref = reference.T_world_cam.cast<float>();
      forBands(ref.depth.rows, photometric_stride, parallel, [&](int c, int v0, int v1) {
        gatherReference(ref, reference.frame->levels[l].confidence, l - pl, T_world_ref, params, photometric_stride, v0,
                        v1, ref_points[c]);
      });
    }
    for (int it = 0; it < iters; ++it) {
      Accumulation acc;
      const Eigen::Isometry3f Tf = T_world_cam.cast<float>();
      accumulateBands(parallel, acc,
                      [&](int c, Accumulation& a) { accumulate(frame_points[c], model[l], Tf, params, a); });
      ++result.iterations;
      if (l == finest) {
        last = acc;  // geometry only: the photometric terms are added below
        have_last = true;
      }
      if (acc.inliers < 6) break;
      if (photometric) {
        const Eigen::Isometry3d T_depth_color =
            reference.color_offset_ratio != 0.0
                ? expSE3(logSE3(reference.T_world_previous.inverse() * T_world_cam) * reference.color_offset_ratio)
                : reference.T_depth_color;
        const Eigen::Isometry3f Tf_color = (T_world_cam * T_depth_color).cast<float>();
        accumulateBands(parallel, acc, [&](int c, Accumulation& a) {
          accumulatePhotometric(frame.levels[pl], ref_points[c], Tf_color, params, a);
        });
        if (l == finest) {
          photometric_abs_sum = acc.photometric_abs_sum;
          photometric_n = acc.photometric_n;
        }
      }
      Eigen::LDLT<Matrix6d> ldlt(acc.eq.H());
      const Vector6d xi = -ldlt.solve(acc.eq.b());
      if (!xi.allFinite()) break;
      T_world_cam = expSE3(xi) * T_world_cam;
      if (xi.head<3>().norm() < params.convergence_rotation_rad &&
          xi.tail<3>().norm() < params.convergence_translation_m) {
        break;
      }
    }
  }
  // The last point-to-plane evaluation at the finest level decides success
  // (at its stride; inlier counts are scaled to every pixel of that level).
  // DESIGN: it is the one the last Gauss-Newton step was computed from, at
  // the pose before that step; a separate evaluation at the final pose cost
  // a tenth of tracking and differs by that step only, small once the
  // finest level has iterated (TUM slice ATE unchanged, 0.53 cm).
  const int final_stride = std::max(1, params.icp_stride_finest);
  if (!have_last) {
    const Eigen::Isometry3f Tf = T_world_cam.cast<float>();
    const FrameBands points = gatherFrameBands(frame.levels[finest], final_stride, parallel);
    accumulateBands(parallel, last,
                    [&](int c, Accumulation& a) { accumulate(points[c], model[finest], Tf, params, a); });
  }
  last.inliers *= final_stride * final_stride;
  last.consistent *= final_stride * final_stride;
  result.inliers = last.inliers;
  result.rms_residual_m = last.inliers > 0 ? std::sqrt(last.sq_sum * final_stride * final_stride / last.inliers) : 0.0;
  result.consistent_ratio = last.inliers > 0 ? static_cast<double>(last.consistent) / last.inliers : 0.0;
  result.mean_abs_residual_m = last.inliers > 0 ? last.abs_sum * final_stride * final_stride / last.inliers : 0.0;
  result.photometric_mean_abs = photometric_n > 0 ? photometric_abs_sum / photometric_n : 0.0;
  result.information = last.eq.H() * static_cast<double>(final_stride * final_stride);
  // DESIGN: the update is in the world frame (T <- exp(xi) T), where a
  // rotation turns about the world's origin: far from it (a long flight,
  // a street 72 m from where the map began) a small rotation moves the
  // camera by meters, the rotation block outgrows the translation block
  // by the distance squared, and every frame looked degenerate. The test
  // takes the information about the camera's center instead: xi = M xi_c,
  // omega the same and v = v_c + c x omega, so H_c = M^T H M, the same
  // wherever the map's origin is.
  Matrix6d M = Matrix6d::Identity();
  M.block<3, 3>(3, 0) = skew(T_world_cam.translation());
  const Matrix6d information_at_camera = M.transpose() * result.information * M;
  Eigen::SelfAdjointEigenSolver<Matrix6d> eig(information_at_camera);
  const double emax = eig.eigenvalues().maxCoeff();
  result.min_eigen_ratio = emax > 0 ? eig.eigenvalues().minCoeff() / emax : 0.0;
  const Eigen::Isometry3d motion = T_init.inverse() * T_world_cam;
  const int reference_pixels = std::max(1, std::min(result.model_pixels, frame.valid_pixels >> (2 * finest)));
  const double inlier_ratio = static_cast<double>(last.inliers) / reference_pixels;
  if (last.inliers < params.min_inliers || inlier_ratio < params.min_inlier_ratio) {
    result.failure = "too few inliers (" + std::to_string(last.inliers) + ")";
  } else if (result.min_eigen_ratio < params.min_hessian_eigenvalue_ratio) {
    result.failure = "degenerate geometry (normal equations near singular)";
  } else if (translationNorm(motion) > params.max_motion_translation_m ||
             rotationAngle(motion) * 180.0 / M_PI > params.max_motion_rotation_deg) {
    result.failure = "implausible motion from the prediction";
  } else if (result.consistent_ratio < params.min_consistent_ratio_lost) {
    result.failure = "residuals beyond the sensor's noise (" + percent(result.consistent_ratio) + " of " +
                     std::to_string(last.inliers) + " associations within the gate)";
  } else {
    result.ok = true;
    result.T_world_cam = T_world_cam;
    if (result.consistent_ratio < params.min_consistent_ratio) {
      result.degraded = percent(result.consistent_ratio) + " of " + std::to_string(last.inliers) +
                        " associations within the noise gate";
    } else if (inlier_ratio < params.min_inlier_ratio_fused) {
      result.degraded = percent(inlier_ratio) + " of the view associated";
    }
  }
  return result;
}

std::vector<ModelView> frameAsModel(const PreprocessedFrame& frame, const Eigen::Isometry3d& T_world_cam) {
  std::vector<ModelView> out;
  if (frame.levels.empty()) return out;
  const Eigen::Isometry3f T_world_cam_f = T_world_cam.cast<float>();
  const Eigen::Matrix3f R = T_world_cam_f.linear();
  const int finest = std::clamp(frame.finest, 0, static_cast<int>(frame.levels.size()) - 1);
  out.resize(frame.levels.size());
  for (size_t l = static_cast<size_t>(finest); l < frame.levels.size(); ++l) {
    const FrameLevel& fl = frame.levels[l];
    ModelView& m = out[l];
    m.camera = fl.camera;
    m.T_world_cam = T_world_cam_f;
    m.depth = fl.depth;
    m.vertex_world.create(fl.vertex.size(), CV_32FC3);
    m.normal_world.create(fl.normal.size(), CV_32FC3);
    for (int v = 0; v < fl.vertex.rows; ++v) {
      const auto* pv = fl.vertex.ptr<cv::Vec3f>(v);
      const auto* pn = fl.normal.ptr<cv::Vec3f>(v);
      auto* wv = m.vertex_world.ptr<cv::Vec3f>(v);
      auto* wn = m.normal_world.ptr<cv::Vec3f>(v);
      for (int u = 0; u < fl.vertex.cols; ++u) {
        const bool valid = pv[u][2] > 0 && (pn[u][0] != 0 || pn[u][1] != 0 || pn[u][2] != 0);
        if (!valid) {
          wv[u] = cv::Vec3f(0, 0, 0);
          wn[u] = cv::Vec3f(0, 0, 0);
          continue;
        }
        const Eigen::Vector3f x = T_world_cam_f * Eigen::Vector3f(pv[u][0], pv[u][1], pv[u][2]);
        const Eigen::Vector3f n = R * Eigen::Vector3f(pn[u][0], pn[u][1], pn[u][2]);
        wv[u] = cv::Vec3f(x.x(), x.y(), x.z());
        wn[u] = cv::Vec3f(n.x(), n.y(), n.z());
        ++m.valid_pixels;
      }
    }
  }
  for (int l = 0; l < finest; ++l) out[static_cast<size_t>(l)] = out[static_cast<size_t>(finest)];
  return out;
}

int modelLevel(const TrackingParams& params, int width) {
  if (params.model_level >= 0) return params.model_level;
  int level = 1;
  while ((width >> (level + 1)) >= 160) ++level;
  return level;
}

bool isNewKeyframe(const Eigen::Isometry3d& T_last_kf, const Eigen::Isometry3d& T_now, int64_t last_kf_ns,
                   int64_t now_ns, const TrackingParams& params, double last_kf_depth_m, double voxel_size_m) {
  const Eigen::Isometry3d rel = T_last_kf.inverse() * T_now;
  double max_translation = params.keyframe_translation_m;
  if (params.keyframe_translation_voxels > 0 && voxel_size_m > 0) {
    max_translation = std::min(max_translation, params.keyframe_translation_voxels * voxel_size_m);
  }
  if (params.keyframe_baseline_ratio > 0 && last_kf_depth_m > 0) {
    max_translation = std::min(max_translation, params.keyframe_baseline_ratio * last_kf_depth_m);
  }
  return translationNorm(rel) > max_translation || rotationAngle(rel) * 180.0 / M_PI > params.keyframe_rotation_deg ||
         static_cast<double>(now_ns - last_kf_ns) * 1e-9 > params.keyframe_interval_s;
}

float medianDepth(const cv::Mat& depth_m) {
  std::vector<float> z;
  z.reserve(depth_m.total());
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* row = depth_m.ptr<float>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      if (row[u] > 0 && std::isfinite(row[u])) z.push_back(row[u]);
    }
  }
  if (z.empty()) return 0.0f;
  auto mid = z.begin() + static_cast<std::ptrdiff_t>(z.size() / 2);
  std::nth_element(z.begin(), mid, z.end());
  return *mid;
}

}  // namespace hxmap::alg
