#include "hxmap/tracking/icp.hpp"

#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

namespace hxmap::alg {

namespace {

struct Accumulation {
  Matrix6d H = Matrix6d::Zero();
  Vector6d b = Vector6d::Zero();
  double sq_sum = 0;
  int inliers = 0;
};

Accumulation accumulate(const FrameLevel& level, const ModelView& model, const Eigen::Isometry3f& T,
                        const TrackingParams& params, int stride) {
  Accumulation acc;
  const Eigen::Isometry3f T_ref_world = model.T_world_cam.inverse();
  const Eigen::Isometry3f T_ref_cam = T_ref_world * T;
  const float max_d = static_cast<float>(params.max_correspondence_distance_m);
  const float cos_max = static_cast<float>(std::cos(params.max_normal_angle_deg * M_PI / 180.0));
  const float huber = static_cast<float>(params.huber_delta_m);
  const PinholeCamera& mc = model.camera;
  const int mw = mc.width, mh = mc.height;
  for (int v = 0; v < level.vertex.rows; v += stride) {
    const auto* vrow = level.vertex.ptr<cv::Vec3f>(v);
    const auto* nrow = level.normal.ptr<cv::Vec3f>(v);
    const float* crow = level.confidence.ptr<float>(v);
    for (int u = 0; u < level.vertex.cols; u += stride) {
      const cv::Vec3f& pc = vrow[u];
      if (pc[2] <= 0 || crow[u] <= 0) continue;
      const cv::Vec3f& nc = nrow[u];
      if (nc[0] == 0 && nc[1] == 0 && nc[2] == 0) continue;
      const Eigen::Vector3f p_cam(pc[0], pc[1], pc[2]);
      const Eigen::Vector3f p_ref = T_ref_cam * p_cam;
      if (p_ref.z() <= 0) continue;
      const int mu = static_cast<int>(std::lround(mc.fx * p_ref.x() / p_ref.z() + mc.cx));
      const int mv = static_cast<int>(std::lround(mc.fy * p_ref.y() / p_ref.z() + mc.cy));
      if (mu < 0 || mv < 0 || mu >= mw || mv >= mh) continue;
      const cv::Vec3f& qn = model.normal_world.ptr<cv::Vec3f>(mv)[mu];
      if (qn[0] == 0 && qn[1] == 0 && qn[2] == 0) continue;
      const cv::Vec3f& qv = model.vertex_world.ptr<cv::Vec3f>(mv)[mu];
      const Eigen::Vector3f q(qv[0], qv[1], qv[2]), n(qn[0], qn[1], qn[2]);
      const Eigen::Vector3f x = T * p_cam;
      if ((x - q).squaredNorm() > max_d * max_d) continue;
      const Eigen::Vector3f n_obs = T.linear() * Eigen::Vector3f(nc[0], nc[1], nc[2]);
      const float cos_n = n_obs.dot(n);
      if (cos_n < cos_max) continue;
      const float r = n.dot(x - q);
      const float ar = std::abs(r);
      const float w_robust = ar <= huber ? 1.0f : huber / ar;
      // w(p): observation confidence and normal consistency.
      const double w = static_cast<double>(crow[u]) * cos_n * w_robust;
      Vector6d J;
      J.head<3>() = x.cross(n).cast<double>();
      J.tail<3>() = n.cast<double>();
      acc.H.selfadjointView<Eigen::Lower>().rankUpdate(J, w);
      acc.b += w * static_cast<double>(r) * J;
      acc.sq_sum += static_cast<double>(r) * r;
      ++acc.inliers;
    }
  }
  return acc;  // lower triangle only; the caller mirrors it
}

inline float bilinear(const cv::Mat& img, float u, float v) {
  const int u0 = static_cast<int>(u), v0 = static_cast<int>(v);
  const float a = u - static_cast<float>(u0), b = v - static_cast<float>(v0);
  const float* r0 = img.ptr<float>(v0) + u0;
  const float* r1 = img.ptr<float>(v0 + 1) + u0;
  return (1 - b) * ((1 - a) * r0[0] + a * r0[1]) + b * ((1 - a) * r1[0] + a * r1[1]);
}

// Photometric residuals r = I_cur(pi(T^-1 T_ref p_ref)) - I_ref(p_ref), added to acc.
void accumulatePhotometric(const FrameLevel& cur, const FrameLevel& ref, const Eigen::Isometry3f& T_world_ref,
                           const Eigen::Isometry3f& T, const TrackingParams& params, int stride, Accumulation& acc) {
  const Eigen::Isometry3f T_cur_world = T.inverse();
  const Eigen::Matrix3f R = T.linear();
  const Eigen::Isometry3f T_cur_ref = T_cur_world * T_world_ref;
  const float fx = static_cast<float>(cur.camera.fx), fy = static_cast<float>(cur.camera.fy);
  const float cx = static_cast<float>(cur.camera.cx), cy = static_cast<float>(cur.camera.cy);
  const float scale = static_cast<float>(params.photometric_scale_m);
  const float huber = static_cast<float>(params.photometric_huber);
  const float gmin2 = static_cast<float>(params.photometric_min_gradient * params.photometric_min_gradient);
  const float W = static_cast<float>(cur.intensity.cols - 2), H = static_cast<float>(cur.intensity.rows - 2);
  for (int v = 0; v < ref.vertex.rows; v += stride) {
    const auto* vrow = ref.vertex.ptr<cv::Vec3f>(v);
    const float* irow = ref.intensity.ptr<float>(v);
    const float* crow = ref.confidence.ptr<float>(v);
    for (int u = 0; u < ref.vertex.cols; u += stride) {
      const cv::Vec3f& pr = vrow[u];
      if (pr[2] <= 0 || crow[u] <= 0) continue;
      const Eigen::Vector3f p_ref(pr[0], pr[1], pr[2]);
      const Eigen::Vector3f pc = T_cur_ref * p_ref;
      if (pc.z() <= 0.05f) continue;
      const float inv_z = 1.0f / pc.z();
      const float uu = fx * pc.x() * inv_z + cx, vv = fy * pc.y() * inv_z + cy;
      if (!(uu >= 0.0f && vv >= 0.0f && uu < W && vv < H)) continue;
      // Occlusion: the current depth there must agree with the warped point.
      const float zc = cur.depth.ptr<float>(static_cast<int>(vv + 0.5f))[static_cast<int>(uu + 0.5f)];
      if (!(zc > 0.0f) || std::abs(zc - pc.z()) > 0.03f + 0.02f * pc.z()) continue;
      const float gx = bilinear(cur.grad_x, uu, vv), gy = bilinear(cur.grad_y, uu, vv);
      if (gx * gx + gy * gy < gmin2) continue;
      const float r = bilinear(cur.intensity, uu, vv) - irow[u];
      // d r / d p_cur = g * d pi / d p.
      const Eigen::Vector3f g(gx * fx * inv_z, gy * fy * inv_z,
                              -(gx * fx * pc.x() + gy * fy * pc.y()) * inv_z * inv_z);
      // p_cur = T^-1 y with y in the world; left perturbation of T gives
      // d r / d omega = (a x y)^T, d r / d v = -a^T with a = R g.
      const Eigen::Vector3f y = T_world_ref * p_ref;
      const Eigen::Vector3f a = R * g;
      Vector6d J;
      J.head<3>() = (scale * a.cross(y)).cast<double>();
      J.tail<3>() = (-scale * a).cast<double>();
      const float ar = std::abs(r);
      const double w = static_cast<double>(crow[u]) * (ar <= huber ? 1.0f : huber / ar);
      acc.H.selfadjointView<Eigen::Lower>().rankUpdate(J, w);
      acc.b += w * static_cast<double>(scale * r) * J;
    }
  }
}

}  // namespace

IcpResult trackPointToPlane(const PreprocessedFrame& frame, const std::vector<ModelView>& model,
                            const Eigen::Isometry3d& T_init, const TrackingParams& params,
                            const PhotometricReference& reference) {
  IcpResult result;
  result.T_world_cam = T_init;
  if (model.empty() || frame.levels.empty()) {
    result.failure = "no model or no frame";
    return result;
  }
  result.model_pixels = model[0].valid_pixels;
  const int levels = static_cast<int>(std::min(model.size(), frame.levels.size()));
  const int iterations[3] = {params.iterations_level0, params.iterations_level1, params.iterations_level2};
  Eigen::Isometry3d T = T_init;
  const bool use_photometric = reference.frame != nullptr && params.photometric_scale_m > 0 &&
                               frame.has_color && reference.frame->has_color;
  for (int l = levels - 1; l >= 0; --l) {
    const int iters = l < 3 ? iterations[l] : params.iterations_level2;
    for (int it = 0; it < iters; ++it) {
      Accumulation acc =
          accumulate(frame.levels[l], model[l], T.cast<float>(), params, l == 0 ? params.icp_stride_level0 : 1);
      ++result.iterations;
      if (acc.inliers < 6) break;
      if (use_photometric && static_cast<size_t>(l) < reference.frame->levels.size()) {
        accumulatePhotometric(frame.levels[l], reference.frame->levels[l], reference.T_world_cam.cast<float>(),
                              T.cast<float>(), params, l == 0 ? params.photometric_stride_level0 : 1, acc);
      }
      acc.H.triangularView<Eigen::Upper>() = acc.H.transpose();  // both passes fill the lower triangle
      Eigen::LDLT<Matrix6d> ldlt(acc.H);
      const Vector6d xi = -ldlt.solve(acc.b);
      if (!xi.allFinite()) break;
      T = expSE3(xi) * T;
      if (xi.head<3>().norm() < params.convergence_rotation_rad && xi.tail<3>().norm() < params.convergence_translation_m) {
        break;
      }
    }
  }
  // Final evaluation at full resolution decides success.
  Accumulation last = accumulate(frame.levels[0], model[0], T.cast<float>(), params, 1);
  result.inliers = last.inliers;
  result.rms_residual_m = last.inliers > 0 ? std::sqrt(last.sq_sum / last.inliers) : 0.0;
  last.H.triangularView<Eigen::Upper>() = last.H.transpose();
  result.information = last.H;
  Eigen::SelfAdjointEigenSolver<Matrix6d> eig(last.H);
  const double emax = eig.eigenvalues().maxCoeff();
  result.min_eigen_ratio = emax > 0 ? eig.eigenvalues().minCoeff() / emax : 0.0;
  const Eigen::Isometry3d motion = T_init.inverse() * T;
  if (last.inliers < params.min_inliers ||
      last.inliers < params.min_inlier_ratio * std::max(1, std::min(result.model_pixels, frame.valid_pixels))) {
    result.failure = "too few inliers (" + std::to_string(last.inliers) + ")";
  } else if (result.rms_residual_m > params.max_rms_residual_m) {
    result.failure = "residual too large (" + std::to_string(result.rms_residual_m * 1000) + " mm rms)";
  } else if (result.min_eigen_ratio < params.min_hessian_eigenvalue_ratio) {
    result.failure = "degenerate geometry (normal equations near singular)";
  } else if (translationNorm(motion) > params.max_motion_translation_m ||
             rotationAngle(motion) * 180.0 / M_PI > params.max_motion_rotation_deg) {
    result.failure = "implausible motion from the prediction";
  } else {
    result.ok = true;
    result.T_world_cam = T;
  }
  return result;
}

bool isNewKeyframe(const Eigen::Isometry3d& T_last_kf, const Eigen::Isometry3d& T_now, int64_t last_kf_ns,
                   int64_t now_ns, const TrackingParams& params) {
  const Eigen::Isometry3d rel = T_last_kf.inverse() * T_now;
  return translationNorm(rel) > params.keyframe_translation_m ||
         rotationAngle(rel) * 180.0 / M_PI > params.keyframe_rotation_deg ||
         static_cast<double>(now_ns - last_kf_ns) * 1e-9 > params.keyframe_interval_s;
}

}  // namespace hxmap::alg
