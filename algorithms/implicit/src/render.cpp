#include "hxmap/implicit/render.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "hxmap/implicit/activation.hpp"

namespace hxmap::alg {

namespace {

uint64_t nextRandom(uint64_t& s) {
  uint64_t z = (s += 0x9E3779B97F4A7C15ULL);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}
float uniform01(uint64_t& s) { return static_cast<float>(nextRandom(s) >> 40) * 0x1.0p-24f; }

/// Ray-box slab test; false when the ray misses.
bool clipToBox(const Eigen::AlignedBox3f& box, const Eigen::Vector3f& o, const Eigen::Vector3f& d, float& t0,
               float& t1) {
  t0 = 0.0f;
  t1 = std::numeric_limits<float>::max();
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12f) {
      if (o[a] < box.min()[a] || o[a] > box.max()[a]) return false;
      continue;
    }
    float ta = (box.min()[a] - o[a]) / d[a], tb = (box.max()[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  return t0 < t1;
}

inline float huber(float r, float delta) {
  const float a = std::abs(r);
  return a <= delta ? 0.5f * r * r : delta * (a - 0.5f * delta);
}
inline float huberGrad(float r, float delta) { return std::abs(r) <= delta ? r : (r > 0 ? delta : -delta); }

void stratified(float a, float b, int n, bool jitter, uint64_t& rng, float* out) {
  const float step = (b - a) / static_cast<float>(n);
  for (int k = 0; k < n; ++k) out[k] = a + (static_cast<float>(k) + (jitter ? uniform01(rng) : 0.5f)) * step;
}

}  // namespace

const char* refinePhaseName(RefinePhase phase) {
  switch (phase) {
    case RefinePhase::kOutside:
      return "outside";
    case RefinePhase::kPrepare:
      return "prepare";
    case RefinePhase::kTrace:
      return "trace";
    case RefinePhase::kSample:
      return "sample";
    case RefinePhase::kForward:
      return "forward";
    case RefinePhase::kRender:
      return "render+loss";
    case RefinePhase::kBackward:
      return "backward";
    case RefinePhase::kOptimizer:
      return "optimizer";
    case RefinePhase::kBookkeeping:
      return "bookkeeping";
    case RefinePhase::kWriteBack:
      return "write-back";
  }
  return "?";
}

std::vector<TrainingRay> collectRays(const std::vector<KeyframeImages>& keyframes, const Eigen::AlignedBox3f& box,
                                     const ImplicitParams& params,
                                     const std::function<bool(const TrainingRay&)>& keep_free) {
  std::vector<TrainingRay> rays, free_rays;
  const int stride = std::max(1, params.pixel_stride);
  const bool want_free = keep_free && params.free_space_rays > 0;

  for (const KeyframeImages& kf : keyframes) {
    if (kf.depth.empty() || kf.depth.type() != CV_32F) continue;
    const bool color = !kf.rgb.empty() && kf.rgb.type() == CV_8UC3 && kf.rgb.size() == kf.depth.size();
    const bool normals = !kf.normal.empty() && kf.normal.type() == CV_32FC3 && kf.normal.size() == kf.depth.size();
    const Eigen::Vector3f origin = kf.T_world_cam.translation();
    const Eigen::Matrix3f R = kf.T_world_cam.linear();
    // Only the pixels whose rays can meet the box: its corners' image
    // (every pixel when the box reaches behind the camera).
    int u0 = 0, v0 = 0, u1 = kf.depth.cols, v1 = kf.depth.rows;
    {
      const Eigen::Isometry3f T_cam_world = kf.T_world_cam.inverse();
      float lo_u = std::numeric_limits<float>::max(), lo_v = lo_u, hi_u = -lo_u, hi_v = -lo_u;
      bool behind = false;
      for (int c = 0; c < 8 && !behind; ++c) {
        const Eigen::Vector3f q = T_cam_world * box.corner(static_cast<Eigen::AlignedBox3f::CornerType>(c));
        behind = !(q.z() > 1e-3f);
        const float pu = static_cast<float>(kf.camera.fx) * q.x() / q.z() + static_cast<float>(kf.camera.cx);
        const float pv = static_cast<float>(kf.camera.fy) * q.y() / q.z() + static_cast<float>(kf.camera.cy);
        lo_u = std::min(lo_u, pu), hi_u = std::max(hi_u, pu), lo_v = std::min(lo_v, pv), hi_v = std::max(hi_v, pv);
      }
      if (!behind) {
        u0 = static_cast<int>(std::clamp(std::floor(lo_u) - 1.0f, 0.0f, static_cast<float>(u1)));
        v0 = static_cast<int>(std::clamp(std::floor(lo_v) - 1.0f, 0.0f, static_cast<float>(v1)));
        u1 = static_cast<int>(std::clamp(std::ceil(hi_u) + 2.0f, 0.0f, static_cast<float>(u1)));
        v1 = static_cast<int>(std::clamp(std::ceil(hi_v) + 2.0f, 0.0f, static_cast<float>(v1)));
      }
    }
    u0 = (u0 + stride - 1) / stride * stride;  // on the stride's lattice
    v0 = (v0 + stride - 1) / stride * stride;
    for (int v = v0; v < v1; v += stride) {
      const float* zrow = kf.depth.ptr<float>(v);
      for (int u = u0; u < u1; u += stride) {
        const float z = zrow[u];
        if (!(z > 0.0f) || !std::isfinite(z)) continue;
        const Eigen::Vector3f p =
            kf.T_world_cam * kf.camera.backproject(static_cast<float>(u), static_cast<float>(v), z);
        const bool inside = box.contains(p);
        if (!inside && !want_free) continue;
        TrainingRay r;
        r.origin = origin;
        r.t_obs = (p - origin).norm();
        if (!(r.t_obs > 1e-4f)) continue;
        r.dir = (p - origin) / r.t_obs;
        if (!clipToBox(box, origin, r.dir, r.t_in, r.t_out)) continue;
        r.keyframe = kf.id;
        if (!inside) {
          r.free_space = r.t_obs > r.t_out;
          if (r.free_space && keep_free(r)) free_rays.push_back(r);
          continue;
        }
        if (color) {
          const cv::Vec3b c = kf.rgb.at<cv::Vec3b>(v, u);
          r.rgb = Eigen::Vector3f(c[0], c[1], c[2]) / 255.0f;
          r.has_color = true;
        }
        if (normals) {
          const cv::Vec3f n = kf.normal.at<cv::Vec3f>(v, u);
          const Eigen::Vector3f nc(n[0], n[1], n[2]);
          if (std::abs(nc.squaredNorm() - 1.0f) < 0.1f) r.normal = R * nc;
        }
        rays.push_back(r);
      }
    }
  }
  auto spread = [](std::vector<TrainingRay>& v, size_t cap) {  // an even spread over all keyframes' rays
    if (v.size() <= cap) return;
    std::vector<TrainingRay> kept;
    kept.reserve(cap);
    const double step = static_cast<double>(v.size()) / static_cast<double>(cap);
    for (size_t i = 0; i < cap; ++i) kept.push_back(v[static_cast<size_t>(static_cast<double>(i) * step)]);
    v.swap(kept);
  };
  spread(rays, static_cast<size_t>(std::max(1, params.max_rays)));
  spread(free_rays, static_cast<size_t>(std::max(0, params.free_space_rays)));
  rays.insert(rays.end(), free_rays.begin(), free_rays.end());
  return rays;
}

std::vector<float> sphereTrace(const NeuralField& field, const std::vector<TrainingRay>& rays,
                               const std::vector<int32_t>& which, int max_steps, NeuralField::Cache* scratch) {
  NeuralField::Cache local;
  NeuralField::Cache& cache = scratch ? *scratch : local;
  const size_t n = which.size();
  std::vector<float> hit(n, -1.0f), t(n), s_prev(n);
  std::vector<size_t> active;
  active.reserve(n);
  const float min_step = 0.5f * field.voxelSize();
  Eigen::Matrix3Xf pts(3, static_cast<Eigen::Index>(n));
  Eigen::VectorXf s;
  for (size_t i = 0; i < n; ++i) {
    const TrainingRay& r = rays[static_cast<size_t>(which[i])];
    t[i] = r.t_in;
    pts.col(static_cast<Eigen::Index>(i)) = r.origin + r.t_in * r.dir;
  }
  field.forward(pts, s, nullptr, &cache);
  for (size_t i = 0; i < n; ++i) {
    s_prev[i] = s[static_cast<Eigen::Index>(i)];
    if (s_prev[i] > 0.0f) active.push_back(i);  // entering inside the surface: no front face here
  }
  for (int step = 0; step < max_steps && !active.empty(); ++step) {
    std::vector<size_t> next;
    std::vector<float> t_new(active.size());
    pts.resize(3, static_cast<Eigen::Index>(active.size()));
    size_t m = 0;
    std::vector<size_t> eval;
    for (size_t i : active) {
      const TrainingRay& r = rays[static_cast<size_t>(which[i])];
      const float tn = t[i] + std::max(0.8f * s_prev[i], min_step);
      if (tn > r.t_out) continue;  // left the box: no surface
      t_new[m] = tn;
      pts.col(static_cast<Eigen::Index>(m)) = r.origin + tn * r.dir;
      eval.push_back(i);
      ++m;
    }
    if (m == 0) break;
    pts.conservativeResize(3, static_cast<Eigen::Index>(m));
    field.forward(pts, s, nullptr, &cache);
    for (size_t k = 0; k < m; ++k) {
      const size_t i = eval[k];
      const float sk = s[static_cast<Eigen::Index>(k)];
      if (sk <= 0.0f) {
        hit[i] = t[i] + (t_new[k] - t[i]) * s_prev[i] / std::max(s_prev[i] - sk, 1e-12f);
      } else {
        t[i] = t_new[k];
        s_prev[i] = sk;
        next.push_back(i);
      }
    }
    active.swap(next);
  }
  return hit;
}

RenderBatch sampleBatch(const NeuralField& field, const std::vector<TrainingRay>& rays, std::vector<int32_t> which,
                        const ImplicitParams& params, bool jitter, uint64_t& rng, RefineProbe* probe,
                        NeuralField::Cache* scratch) {
  RenderBatch b;
  if (rays.empty()) return b;
  if (which.empty()) {
    const auto n = static_cast<size_t>(std::max(1, params.rays_per_iteration));
    // Free-space rays come last (collectRays); they get their own share of
    // the batch: a thick shadow takes many steps to clear, and at their
    // share of the candidates (about a seventh) jobs converged first.
    const auto first_free = static_cast<size_t>(
        std::partition_point(rays.begin(), rays.end(), [](const TrainingRay& r) { return !r.free_space; }) -
        rays.begin());
    const size_t n_free = rays.size() - first_free;
    const size_t k_free =
        first_free == 0 ? n
        : n_free == 0   ? 0
                        : std::min(n, static_cast<size_t>(std::lround(static_cast<double>(n) *
                                                                      std::clamp(params.free_space_share, 0.0, 1.0))));
    which.resize(n);
    for (size_t k = 0; k < n; ++k) {
      which[k] =
          static_cast<int32_t>(k < n - k_free ? nextRandom(rng) % first_free : first_free + nextRandom(rng) % n_free);
    }
  }
  b.rays = std::move(which);
  const int N = std::max(4, params.samples_per_ray);
  b.samples = N;
  b.t.resize(b.rays.size() * static_cast<size_t>(N));
  enterPhase(probe, RefinePhase::kTrace);
  const std::vector<float> hit = sphereTrace(field, rays, b.rays, params.sphere_trace_steps, scratch);
  enterPhase(probe, RefinePhase::kSample);
  const float band = static_cast<float>(params.sample_band_voxels) * field.voxelSize();
  std::vector<size_t> with_hit;
  for (size_t i = 0; i < b.rays.size(); ++i) {
    const TrainingRay& r = rays[static_cast<size_t>(b.rays[i])];
    float* t = &b.t[i * static_cast<size_t>(N)];
    const float th = hit[i];
    if (r.free_space) {  // around the field's surface, or over the whole crossing
      if (th >= 0.0f) {
        stratified(th - band, th + band, N, jitter, rng, t);
      } else {
        stratified(r.t_in, r.t_out, N, jitter, rng, t);
      }
    } else if (th < 0.0f || std::abs(th - r.t_obs) <= 2.0f * band) {
      const float lo = (th < 0.0f ? r.t_obs : std::min(th, r.t_obs)) - band;
      const float hi = (th < 0.0f ? r.t_obs : std::max(th, r.t_obs)) + band;
      stratified(lo, hi, N, jitter, rng, t);
    } else {  // the field's surface and the observation disagree: sample both
      const int half = N / 2;
      stratified(r.t_obs - band, r.t_obs + band, half, jitter, rng, t);
      stratified(th - band, th + band, N - half, jitter, rng, t + half);
      std::sort(t, t + N);
    }
    for (int k = 0; k < N; ++k) t[k] = std::clamp(t[k], r.t_in, r.t_out);
    if (th >= 0.0f && !r.free_space) with_hit.push_back(i);
  }
  // Regularizer points: traced surfaces first (with the measured normal),
  // then random samples (eikonal only).
  const size_t P = static_cast<size_t>(std::max(0, params.regularizer_points));
  for (size_t k = 0; k < with_hit.size() && b.reg_points.size() < P; ++k) {
    const size_t i = with_hit[k];
    const TrainingRay& r = rays[static_cast<size_t>(b.rays[i])];
    b.reg_points.push_back(r.origin + hit[i] * r.dir);
    b.reg_normals.push_back(r.normal);
  }
  while (b.reg_points.size() < P) {
    const size_t i = nextRandom(rng) % b.rays.size();
    const TrainingRay& r = rays[static_cast<size_t>(b.rays[i])];
    const float t = b.t[i * static_cast<size_t>(N) + nextRandom(rng) % static_cast<size_t>(N)];
    b.reg_points.push_back(r.origin + t * r.dir);
    b.reg_normals.push_back(Eigen::Vector3f::Zero());
  }
  return b;
}

LossTerms evaluateLoss(const NeuralField& field, const std::vector<TrainingRay>& rays, const RenderBatch& batch,
                       const ImplicitParams& params, std::vector<float>* grad, TouchedNodes* touched,
                       Rendering* rendering, RefineProbe* probe, NeuralField::Cache* cache) {
  LossTerms L;
  const size_t R = batch.rays.size(), P = batch.reg_points.size();
  const int N = batch.samples;
  if (R == 0 || N < 2) return L;
  const size_t n_samples = R * static_cast<size_t>(N);
  const auto total = static_cast<Eigen::Index>(n_samples + 6 * P);
  const float h = 0.5f * field.voxelSize();
  Eigen::Matrix3Xf pts(3, total);
  for (size_t i = 0; i < R; ++i) {
    const TrainingRay& r = rays[static_cast<size_t>(batch.rays[i])];
    for (int k = 0; k < N; ++k) {
      const size_t j = i * static_cast<size_t>(N) + static_cast<size_t>(k);
      pts.col(static_cast<Eigen::Index>(j)) = r.origin + batch.t[j] * r.dir;
    }
  }
  for (size_t p = 0; p < P; ++p) {
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3f e = Eigen::Vector3f::Zero();
      e[a] = h;
      pts.col(static_cast<Eigen::Index>(n_samples + 6 * p + 2 * a)) = batch.reg_points[p] + e;
      pts.col(static_cast<Eigen::Index>(n_samples + 6 * p + 2 * a + 1)) = batch.reg_points[p] - e;
    }
  }
  NeuralField::Cache local;
  NeuralField::Cache& c = cache ? *cache : local;
  Eigen::VectorXf s;
  Eigen::Matrix3Xf rgb;
  enterPhase(probe, RefinePhase::kForward);
  field.forward(pts, s, &rgb, &c);
  enterPhase(probe, RefinePhase::kRender);

  Eigen::VectorXf ds = Eigen::VectorXf::Zero(total);
  Eigen::Matrix3Xf drgb = Eigen::Matrix3Xf::Zero(3, total);
  const float vs = field.voxelSize();
  const float beta = static_cast<float>(params.sharpness_voxels) * vs;
  const float inv_r = 1.0f / static_cast<float>(R);
  const float lam_d = static_cast<float>(params.lambda_depth), lam_p = static_cast<float>(params.lambda_photo);
  const float dd = static_cast<float>(params.depth_huber_voxels), dp = static_cast<float>(params.photo_huber);
  if (rendering) {
    rendering->depth.assign(R, 0.0f);
    rendering->transmittance.assign(n_samples, 0.0f);
  }
  // log Phi(x) = -softplus(-x) and Phi(-x) = softplus'(-x) of every
  // sample's x = s / beta, in one vectorized pass.
  std::vector<float> neg_x(n_samples), softplus_neg(n_samples), sigmoid_neg(n_samples);
  for (size_t j = 0; j < n_samples; ++j) neg_x[j] = -s[static_cast<Eigen::Index>(j)] / beta;
  softplusAndSlope(neg_x.data(), softplus_neg.data(), sigmoid_neg.data(), n_samples);
  std::vector<float> logphi(static_cast<size_t>(N)), alpha(static_cast<size_t>(N)), ratio(static_cast<size_t>(N)),
      T(static_cast<size_t>(N)), w(static_cast<size_t>(N)), g(static_cast<size_t>(N));
  std::vector<Eigen::Vector3f> cbar(static_cast<size_t>(N));
  double sum_photo = 0, sum_depth = 0;
  for (size_t i = 0; i < R; ++i) {
    const TrainingRay& r = rays[static_cast<size_t>(batch.rays[i])];
    const size_t j0 = i * static_cast<size_t>(N);
    const float* t = &batch.t[j0];
    for (int k = 0; k < N; ++k) logphi[k] = -softplus_neg[j0 + k];
    const int M = N - 1;  // sections
    float Ti = 1.0f, W = 0.0f;
    const float t_far = t[N - 1];
    float D = t_far;
    for (int k = 0; k < M; ++k) {
      ratio[k] = std::exp(logphi[k + 1] - logphi[k]);
      alpha[k] = std::max(0.0f, 1.0f - ratio[k]);
      T[k] = Ti;
      w[k] = Ti * alpha[k];
      Ti *= 1.0f - alpha[k];
      W += w[k];
      D += w[k] * (0.5f * (t[k] + t[k + 1]) - t_far);
    }
    if (rendering) {
      rendering->depth[i] = D;
      for (int k = 0; k < M; ++k) rendering->transmittance[j0 + k] = T[k];
      rendering->transmittance[j0 + M] = Ti;
    }
    // A free-space ray renders no surface in the box: its depth is the far
    // end of its samples.
    const float rd = (D - (r.free_space ? t_far : r.t_obs)) / vs;
    sum_depth += huber(rd, dd);
    const float dLdD = lam_d * inv_r * huberGrad(rd, dd) / vs;
    for (int k = 0; k < M; ++k) g[k] = dLdD * (0.5f * (t[k] + t[k + 1]) - t_far);
    if (r.has_color && !r.free_space && W > 0.1f) {
      Eigen::Vector3f C = Eigen::Vector3f::Zero();
      for (int k = 0; k < M; ++k) {
        cbar[k] = 0.5f * (rgb.col(static_cast<Eigen::Index>(j0 + k)) + rgb.col(static_cast<Eigen::Index>(j0 + k + 1)));
        C += w[k] * cbar[k];
      }
      C /= W;
      const Eigen::Vector3f e = C - r.rgb;
      Eigen::Vector3f dLdC;
      for (int a = 0; a < 3; ++a) {
        sum_photo += huber(e[a], dp);
        dLdC[a] = lam_p * inv_r * huberGrad(e[a], dp);
      }
      ++L.photo_rays;
      for (int k = 0; k < M; ++k) {
        g[k] += dLdC.dot(cbar[k] - C) / W;
        const Eigen::Vector3f dc = dLdC * (0.5f * w[k] / W);
        drgb.col(static_cast<Eigen::Index>(j0 + k)) += dc;
        drgb.col(static_cast<Eigen::Index>(j0 + k + 1)) += dc;
      }
    }
    if (!grad) continue;
    // Compositing backward: dL/dalpha_k = T_k (g_k - after_{k+1}), with
    // after_k the ray's value from section k on as seen with T_k = 1.
    float after = 0.0f;
    for (int k = M - 1; k >= 0; --k) {
      const float da = T[k] * (g[k] - after);
      after = alpha[k] * g[k] + (1.0f - alpha[k]) * after;
      if (alpha[k] <= 0.0f) continue;  // clamped: no gradient
      ds[static_cast<Eigen::Index>(j0 + k)] += da * ratio[k] * sigmoid_neg[j0 + k] / beta;
      ds[static_cast<Eigen::Index>(j0 + k + 1)] -= da * ratio[k] * sigmoid_neg[j0 + k + 1] / beta;
    }
  }
  L.rays = static_cast<int>(R);
  L.depth = sum_depth * inv_r;
  L.photo = sum_photo * inv_r;

  // Normal consistency and eikonal at the regularizer points.
  int n_normal = 0;
  for (size_t p = 0; p < P; ++p) n_normal += batch.reg_normals[p].squaredNorm() > 0.5f;
  const float lam_e = P ? static_cast<float>(params.lambda_eikonal) / static_cast<float>(P) : 0.0f;
  const float lam_n = n_normal ? static_cast<float>(params.lambda_normal) / static_cast<float>(n_normal) : 0.0f;
  double sum_eik = 0, sum_normal = 0;
  for (size_t p = 0; p < P; ++p) {
    const auto c0 = static_cast<Eigen::Index>(n_samples + 6 * p);
    Eigen::Vector3f gr;
    for (int a = 0; a < 3; ++a) gr[a] = (s[c0 + 2 * a] - s[c0 + 2 * a + 1]) / (2.0f * h);
    const float len = gr.norm();
    sum_eik += (len - 1.0f) * (len - 1.0f);
    Eigen::Vector3f dg = Eigen::Vector3f::Zero();
    if (len > 1e-6f) dg += lam_e * 2.0f * (len - 1.0f) * gr / len;
    const Eigen::Vector3f& ne = batch.reg_normals[p];
    if (ne.squaredNorm() > 0.5f && len > 1e-6f) {
      const Eigen::Vector3f nh = gr / len;
      sum_normal += 1.0f - nh.dot(ne);
      dg += lam_n * (-(ne - nh.dot(ne) * nh) / len);
    }
    for (int a = 0; a < 3; ++a) {
      ds[c0 + 2 * a] += dg[a] / (2.0f * h);
      ds[c0 + 2 * a + 1] -= dg[a] / (2.0f * h);
    }
  }
  L.reg_points = static_cast<int>(P);
  L.normal_points = n_normal;
  L.eikonal = P ? sum_eik / static_cast<double>(P) : 0.0;
  L.normal = n_normal ? sum_normal / n_normal : 0.0;
  L.total = params.lambda_photo * L.photo + params.lambda_depth * L.depth + params.lambda_normal * L.normal +
            params.lambda_eikonal * L.eikonal;
  if (grad) {
    enterPhase(probe, RefinePhase::kBackward);
    field.backward(c, ds, drgb, *grad, touched);
  }
  return L;
}

}  // namespace hxmap::alg
