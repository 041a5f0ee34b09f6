#include "hxmap/feedback/window.hpp"

#include <algorithm>
#include <cmath>
#include <memory>

#include <Eigen/Cholesky>

namespace hxmap::alg {

namespace {

// Huber with threshold 1 on a normalized residual: cost and IRLS weight.
inline double huberCost(double x) {
  const double a = std::abs(x);
  return a <= 1.0 ? 0.5 * x * x : a - 0.5;
}
inline double huberWeight(double x) {
  const double a = std::abs(x);
  return a <= 1.0 ? 1.0 : 1.0 / a;
}

uint64_t nextRandom(uint64_t& s) {  // xorshift64*
  s ^= s >> 12;
  s ^= s << 25;
  s ^= s >> 27;
  return s * 2685821657736338717ull;
}

// One normalized residual into H, b and the cost.
void accumulate(double r, double sigma, double lambda, const Vector6d& J, Matrix6d& H, Vector6d& b, double& cost) {
  const double x = r / sigma;
  const double w = lambda * huberWeight(x) / (sigma * sigma);
  H.selfadjointView<Eigen::Upper>().rankUpdate(J, w);
  b += w * r * J;
  cost += lambda * huberCost(x);
}

}  // namespace

PoseWindow::PoseWindow(const FeedbackParams& params)
    : params_(params), rng_state_(0x9E3779B97F4A7C15ull ^ (static_cast<uint64_t>(params.seed) + 1)) {}

void PoseWindow::prepare(Slot& slot, const WindowKeyframe& kf) const {
  // Into a new buffer: the keyframe's intensity is shared with its frame
  // (the frontend's photometric reference, read on another thread).
  cv::Mat I = kf.intensity;
  if (params_.photo_blur_px > 0) {
    I = cv::Mat();
    cv::GaussianBlur(kf.intensity, I, cv::Size(0, 0), params_.photo_blur_px);
  }
  slot.intensity = I;
  slot.grad_x = cv::Mat(I.size(), CV_32F, cv::Scalar(0));
  slot.grad_y = cv::Mat(I.size(), CV_32F, cv::Scalar(0));
  std::vector<Eigen::Vector2i> valid;
  slot.usable = cv::Mat(I.size(), CV_8U, cv::Scalar(0));
  const float edge_ratio = static_cast<float>(params_.edge_depth_ratio);
  for (int v = 1; v + 1 < I.rows; ++v) {
    const float* row = I.ptr<float>(v);
    const float* up = I.ptr<float>(v - 1);
    const float* down = I.ptr<float>(v + 1);
    const float* d = kf.depth.ptr<float>(v);
    float* gx = slot.grad_x.ptr<float>(v);
    float* gy = slot.grad_y.ptr<float>(v);
    for (int u = 1; u + 1 < I.cols; ++u) {
      gx[u] = 0.5f * (row[u + 1] - row[u - 1]);
      gy[u] = 0.5f * (down[u] - up[u]);
      if (!(d[u] > 0) || !std::isfinite(d[u])) continue;
      // Not next to a depth edge or a hole: at silhouettes the map's
      // surface and the image's disagree by construction (fusion rounds
      // edges, the sensor mixes foreground and background), and those
      // residuals bias the solve.
      const float du = kf.depth.ptr<float>(v - 1)[u], dd = kf.depth.ptr<float>(v + 1)[u];
      const float jump = edge_ratio * d[u];
      if (!(std::abs(d[u - 1] - d[u]) < jump && std::abs(d[u + 1] - d[u]) < jump && std::abs(du - d[u]) < jump &&
            std::abs(dd - d[u]) < jump)) {
        continue;
      }
      valid.emplace_back(u, v);
      slot.usable.ptr<uint8_t>(v)[u] = 1;
    }
  }
  // Uniform base: systematic sampling of the pixels with depth.
  slot.base.clear();
  const size_t want = static_cast<size_t>(std::max(0, params_.base_pixels));
  if (valid.size() <= want) {
    slot.base = valid;
  } else {
    const double step = static_cast<double>(valid.size()) / static_cast<double>(want);
    for (size_t k = 0; k < want; ++k) slot.base.push_back(valid[static_cast<size_t>((static_cast<double>(k) + 0.5) * step)]);
  }
  slot.extra.clear();
  slot.base_samples.clear();
  slot.extra_samples.clear();
  for (const Eigen::Vector2i& px : slot.base) {
    const int u = px.x(), v = px.y();
    slot.base_samples.push_back({u, v, kf.depth.at<float>(v, u), I.at<float>(v, u), slot.grad_x.at<float>(v, u),
                                 slot.grad_y.at<float>(v, u)});
  }
}

PoseWindow::Verification PoseWindow::verify(size_t j, const Eigen::Isometry3d& from, const Eigen::Isometry3d& to,
                                            const FeedbackMaps& maps, const std::function<bool()>& stop) const {
  Verification out;
  if (j >= slots_.size() || params_.verify_stride <= 0) return out;
  const Slot& slot = slots_[j];
  const int stride = params_.verify_stride;
  std::vector<Eigen::Vector2i> pixels;
  for (int v = stride / 2; v < slot.usable.rows; v += stride) {
    const uint8_t* row = slot.usable.ptr<uint8_t>(v);
    for (int u = stride / 2; u < slot.usable.cols; u += stride) {
      if (row[u]) pixels.emplace_back(u, v);
    }
  }
  out.pixels = static_cast<int>(pixels.size());
  const std::vector<PixelSample> samples = gather(j, pixels);
  // In chunks of a window keyframe's size, each a slice the caller admits.
  auto evaluate = [&](const Eigen::Isometry3d& T_world_kf) {
    constexpr size_t kChunk = 2048;
    Linearization sum;
    std::vector<PixelSample> chunk;
    for (size_t begin = 0; begin < samples.size() && !out.stopped; begin += kChunk) {
      if (stop && stop()) {
        out.stopped = true;
        break;
      }
      chunk.assign(samples.begin() + static_cast<std::ptrdiff_t>(begin),
                   samples.begin() + static_cast<std::ptrdiff_t>(std::min(samples.size(), begin + kChunk)));
      const Linearization l = linearizeSamples(j, T_world_kf, maps, chunk, nullptr);
      sum.cost += l.cost;
      sum.depth_cost += l.depth_cost;
      sum.photo_cost += l.photo_cost;
      sum.counts.depth_explicit += l.counts.depth_explicit;
      sum.counts.depth_implicit += l.counts.depth_implicit;
      sum.counts.photo_explicit += l.counts.photo_explicit;
      sum.counts.photo_implicit += l.counts.photo_implicit;
    }
    return sum;
  };
  const Linearization a = evaluate(from);
  const Linearization b = evaluate(to);
  // A residual counted at one pose only is charged at the other as one at
  // its gate (each channel with its own weight).
  const FeedbackParams& p = params_;
  const double depth_gate = huberCost(p.depth_gate_m / p.depth_sigma_m);
  const double photo_gate = huberCost(p.photo_gate / p.photo_sigma);
  auto charge = [](int na, int nb, double lambda_gate, double& ca, double& cb) {
    ca += std::max(0, nb - na) * lambda_gate;
    cb += std::max(0, na - nb) * lambda_gate;
  };
  out.depth_from = a.depth_cost, out.depth_to = b.depth_cost;
  out.photo_from = a.photo_cost, out.photo_to = b.photo_cost;
  charge(a.counts.depth_explicit, b.counts.depth_explicit, p.lambda_depth_explicit * depth_gate, out.depth_from,
         out.depth_to);
  charge(a.counts.depth_implicit, b.counts.depth_implicit, p.lambda_depth_implicit * depth_gate, out.depth_from,
         out.depth_to);
  charge(a.counts.photo_explicit, b.counts.photo_explicit, p.lambda_photo_explicit * photo_gate, out.photo_from,
         out.photo_to);
  charge(a.counts.photo_implicit, b.counts.photo_implicit, p.lambda_photo_implicit * photo_gate, out.photo_from,
         out.photo_to);
  out.passed = !out.stopped && out.pixels > 0 && out.depth_to <= out.depth_from && out.photo_to <= out.photo_from;
  return out;
}

std::vector<PoseWindow::PixelSample> PoseWindow::gather(size_t j, const std::vector<Eigen::Vector2i>& pixels) const {
  std::vector<PixelSample> out;
  out.reserve(pixels.size());
  const WindowKeyframe& kf = keyframes_[j];
  const Slot& s = slots_[j];
  if (kf.depth.empty() || s.intensity.empty()) return out;
  for (const Eigen::Vector2i& px : pixels) {
    const int u = px.x(), v = px.y();
    if (u < 0 || v < 0 || u >= kf.depth.cols || v >= kf.depth.rows) continue;
    out.push_back({u, v, kf.depth.at<float>(v, u), s.intensity.at<float>(v, u), s.grad_x.at<float>(v, u),
                   s.grad_y.at<float>(v, u)});
  }
  return out;
}

PoseWindow::Linearization PoseWindow::linearize(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps,
                                                const std::vector<Eigen::Vector2i>& pixels,
                                                std::vector<PixelResult>* out) const {
  return linearizeSamples(j, T_world_kf, maps, gather(j, pixels), out);
}

namespace {

// One hit's channels into L: depth (point-to-plane when asked), and
// photometric where the image is textured. `worst` gets the largest
// weighted |r|.
struct ChannelWeights {
  double photo = 0, depth = 0;
};
void addChannels(const FeedbackParams& p, const PinholeCamera& cam, const Eigen::Isometry3d& T_world_kf, double u,
                 double v, double D, double I, double gx, double gy, const SurfaceHit& hit, double cosine,
                 ChannelWeights lambda, int& n_photo, int& n_depth, PoseWindow::Linearization& L, float& worst) {
  Vector6d J;
  // A residual within its gate: into H, b and the cost (and the channel's
  // share of it), counted, and its weighted size kept for Omega's top set.
  auto take = [&](double r, double gate, double sigma, double lambda_c, double& channel_cost, int& count) {
    if (!(std::abs(r) <= gate)) return;
    const double c0 = L.cost;
    accumulate(r, sigma, lambda_c, J, L.H, L.b, L.cost);
    channel_cost += L.cost - c0;
    ++count;
    worst = std::max(worst, static_cast<float>(std::sqrt(lambda_c) * std::abs(r) / sigma));
  };
  if (lambda.depth > 0) {
    double r = depthResidual(cam, T_world_kf, u, v, D, hit, J);
    if (p.depth_point_to_plane) {
      // The along-ray residual times the incidence cosine (held fixed in
      // the step, as an IRLS weight): the distance to the map's tangent plane.
      r *= cosine;
      J *= cosine;
    }
    take(r, p.depth_gate_m, p.depth_sigma_m, lambda.depth, L.depth_cost, n_depth);
  }
  if (lambda.photo > 0 && gx * gx + gy * gy >= p.min_gradient * p.min_gradient) {
    const double r = photoResidual(cam, T_world_kf, u, v, I, gx, gy, hit, J);
    take(r, p.photo_gate, p.photo_sigma, lambda.photo, L.photo_cost, n_photo);
  }
}

// Bilinear sample of a CV_32F image; false outside its interior.
bool bilinear(const cv::Mat& img, double x, double y, double& out) {
  if (!(x >= 0 && y >= 0 && x < img.cols - 1 && y < img.rows - 1)) return false;
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const double fx = x - x0, fy = y - y0;
  const float* r0 = img.ptr<float>(y0) + x0;
  const float* r1 = img.ptr<float>(y0 + 1) + x0;
  out = (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  return true;
}

}  // namespace

PoseWindow::Linearization PoseWindow::linearizeOnPlanes(size_t j, const Eigen::Isometry3d& T_cast,
                                                        const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps,
                                                        const std::vector<Eigen::Vector2i>& pixels, int repeat) const {
  const std::vector<PixelSample> samples = gather(j, pixels);
  std::vector<CachedHit> hits;
  linearizeSamples(j, T_cast, maps, samples, nullptr, &hits);
  Linearization L;
  for (int r = 0; r < std::max(1, repeat); ++r) L = linearizeCached(j, T_world_kf, samples, hits, nullptr);
  return L;
}

PoseWindow::Linearization PoseWindow::linearizeSamples(size_t j, const Eigen::Isometry3d& T_world_kf,
                                                       const FeedbackMaps& maps,
                                                       const std::vector<PixelSample>& samples,
                                                       std::vector<PixelResult>* out,
                                                       std::vector<CachedHit>* hits) const {
  Linearization L;
  if (out) out->assign(samples.size(), PixelResult{});
  if (hits) hits->clear();
  const WindowKeyframe& kf = keyframes_[j];
  if (!maps.tsdf || kf.intensity.empty()) return L;
  BlockCache cache(*maps.tsdf);
  const PinholeCamera& cam = kf.camera;
  const FeedbackParams& p = params_;
  const ChannelWeights explicit_w{p.lambda_photo_explicit, p.lambda_depth_explicit};
  const ChannelWeights implicit_w{p.lambda_photo_implicit, p.lambda_depth_implicit};
  for (size_t i = 0; i < samples.size(); ++i) {
    const PixelSample& px = samples[i];
    const double u = px.u, v = px.v, D = px.depth;
    if (!(D > 0)) continue;
    float worst = 0;
    auto take = [&](const SurfaceHit& hit, bool implicit) {
      const double c = p.depth_point_to_plane ? incidenceCosine(cam, T_world_kf, u, v, hit) : 1.0;
      addChannels(p, cam, T_world_kf, u, v, D, px.intensity, px.gx, px.gy, hit, c, implicit ? implicit_w : explicit_w,
                  implicit ? L.counts.photo_implicit : L.counts.photo_explicit,
                  implicit ? L.counts.depth_implicit : L.counts.depth_explicit, L, worst);
      if (hits) {
        hits->push_back({static_cast<uint32_t>(i), implicit, static_cast<float>(c), hit.point_world, hit.normal_world,
                         hit.intensity});
      }
    };
    SurfaceHit hit;
    if (castExplicit(cache, *maps.tsdf, cam, T_world_kf, u, v, D, p.max_incidence_deg, hit)) {
      take(hit, false);
      if (out) (*out)[i].hint_z = static_cast<float>(hit.z);
      // Implicit channels where the ray meets a refined region's field.
      for (const ImplicitSurface* surface : maps.implicit) {
        if (!surface || !surface->box().contains(hit.point_world.cast<float>())) continue;
        SurfaceHit ih;
        if (castImplicit(*surface, cam, T_world_kf, u, v, hit.z, p.max_incidence_deg, ih)) take(ih, true);
        break;  // one field per ray
      }
    }
    if (out) (*out)[i].residual = worst;
  }
  L.H = L.H.selfadjointView<Eigen::Upper>();
  L.counts.cost = L.cost;
  return L;
}

PoseWindow::Linearization PoseWindow::linearizeCached(size_t j, const Eigen::Isometry3d& T_world_kf,
                                                      const std::vector<PixelSample>& samples,
                                                      const std::vector<CachedHit>& hits,
                                                      std::vector<PixelResult>* out) const {
  Linearization L;
  if (out) out->assign(samples.size(), PixelResult{});
  const WindowKeyframe& kf = keyframes_[j];
  const Slot& slot = slots_[j];
  const PinholeCamera& cam = kf.camera;
  const FeedbackParams& p = params_;
  const ChannelWeights explicit_w{p.lambda_photo_explicit, p.lambda_depth_explicit};
  const ChannelWeights implicit_w{p.lambda_photo_implicit, p.lambda_depth_implicit};
  const Eigen::Matrix3d Rt = T_world_kf.linear().transpose();
  const Eigen::Isometry3d T_inv = T_world_kf.inverse();
  const double min_gradient2 = p.min_gradient * p.min_gradient;
  for (const CachedHit& h : hits) {
    if (h.sample >= samples.size()) continue;
    const PixelSample& px = samples[h.sample];
    const double u = px.u, v = px.v;
    // The pixel's ray meets the hit's tangent plane at depth z.
    const Eigen::Vector3d q = pixelRay(cam, u, v);
    const Eigen::Vector3d n_c = Rt * h.normal_world;
    const double nq = n_c.dot(q);
    if (!(std::abs(nq) > 1e-9)) continue;
    SurfaceHit hit;
    hit.z = n_c.dot(T_inv * h.point_world) / nq;
    if (!(hit.z > 0)) continue;
    hit.point_world = h.point_world;
    hit.normal_world = h.normal_world;
    hit.intensity = h.intensity;
    // The image where the hit point projects now (exactly (u, v) at the pose it was cast from).
    const Eigen::Vector3d x = T_inv * h.point_world;
    // Photometric only where the pixel was textured when cast: the image
    // where the hit projects now (the gradient is the pixel's: it changes
    // to second order over a step).
    double I = px.intensity, gx = px.gx, gy = px.gy;
    if (!(x.z() > 0)) {
      gx = gy = 0;
    } else if (gx * gx + gy * gy >= min_gradient2) {
      const double pu = cam.fx * x.x() / x.z() + cam.cx, pv = cam.fy * x.y() / x.z() + cam.cy;
      if (std::abs(pu - u) + std::abs(pv - v) > 1e-3 && !bilinear(slot.intensity, pu, pv, I)) {
        gx = gy = 0;  // left the image: no photometric residual
      }
    }
    float worst = out ? (*out)[h.sample].residual : 0.0f;
    addChannels(p, cam, T_world_kf, u, v, px.depth, I, gx, gy, hit, h.cosine, h.implicit ? implicit_w : explicit_w,
                h.implicit ? L.counts.photo_implicit : L.counts.photo_explicit,
                h.implicit ? L.counts.depth_implicit : L.counts.depth_explicit, L, worst);
    if (out) (*out)[h.sample].residual = worst;
  }
  L.H = L.H.selfadjointView<Eigen::Upper>();
  L.counts.cost = L.cost;
  return L;
}

double PoseWindow::relativeFactor(size_t a, const Eigen::Isometry3d& Ta, const Eigen::Isometry3d& Tb,
                                  Eigen::Matrix<double, 12, 12>* H, Eigen::Matrix<double, 12, 1>* b) const {
  const WindowKeyframe& kb = keyframes_[a + 1];
  if (!linked(a + 1)) {
    if (H && b) {
      H->setZero();
      b->setZero();
    }
    return 0.0;
  }
  const Matrix6d info = params_.odometry_information_scale * kb.odometry_information;
  Matrix6d Ja, Jb;
  const Vector6d e = relativePoseResidual(kb.odometry_from_previous, Ta, Tb, &Ja, &Jb);
  if (H && b) {
    Eigen::Matrix<double, 6, 12> J;
    J.leftCols<6>() = Ja;
    J.rightCols<6>() = Jb;
    *H = J.transpose() * info * J;
    *b = J.transpose() * info * e;
  }
  return 0.5 * e.dot(info * e);
}

double PoseWindow::priorCost(const Eigen::Isometry3d& T_world_kf, Matrix6d* H, Vector6d* b) const {
  if (!has_prior_) return 0.0;
  const Vector6d d = logSE3(prior_T_lin_.inverse() * T_world_kf);
  if (H && b) {
    *H = prior_H_;
    *b = prior_H_ * d + prior_b_;
  }
  return 0.5 * d.dot(prior_H_ * d) + prior_b_.dot(d);
}

void PoseWindow::add(WindowKeyframe keyframe, const FeedbackMaps& maps) {
  while (params_.window > 0 && keyframes_.size() >= static_cast<size_t>(params_.window)) marginalizeOldest(maps);
  Slot slot;
  prepare(slot, keyframe);
  keyframes_.push_back(std::move(keyframe));
  slots_.push_back(std::move(slot));
}

void PoseWindow::marginalizeOldest(const FeedbackMaps& maps) {
  if (keyframes_.empty()) return;
  if (keyframes_.size() >= 2) {
    // The oldest pose's factors at the current estimates: its residual
    // factor, its prior and the relative factor to the next keyframe.
    Eigen::Matrix<double, 12, 12> H = Eigen::Matrix<double, 12, 12>::Zero();
    Eigen::Matrix<double, 12, 1> b = Eigen::Matrix<double, 12, 1>::Zero();
    const Linearization lo = linearizeSamples(0, keyframes_[0].T_world_cam, maps, slots_[0].base_samples, nullptr);
    H.topLeftCorner<6, 6>() += lo.H;
    b.head<6>() += lo.b;
    if (has_prior_) {
      Matrix6d Hp;
      Vector6d bp;
      priorCost(keyframes_[0].T_world_cam, &Hp, &bp);
      H.topLeftCorner<6, 6>() += Hp;
      b.head<6>() += bp;
    }
    if (linked(1)) {
      Eigen::Matrix<double, 12, 12> Hr;
      Eigen::Matrix<double, 12, 1> br;
      relativeFactor(0, keyframes_[0].T_world_cam, keyframes_[1].T_world_cam, &Hr, &br);
      H += Hr;
      b += br;
      // Schur complement: the oldest pose eliminated.
      const Matrix6d H00 = H.topLeftCorner<6, 6>() + 1e-9 * Matrix6d::Identity();
      const Eigen::LDLT<Matrix6d> ldlt(H00);
      const Matrix6d H10 = H.bottomLeftCorner<6, 6>();
      prior_H_ = H.bottomRightCorner<6, 6>() - H10 * ldlt.solve(H10.transpose());
      prior_H_ = 0.5 * (prior_H_ + prior_H_.transpose());
      prior_b_ = b.tail<6>() - H10 * ldlt.solve(b.head<6>());
      prior_T_lin_ = keyframes_[1].T_world_cam;
      has_prior_ = true;
    } else {
      has_prior_ = false;  // nothing ties the next pose to the one leaving
    }
  } else {
    has_prior_ = false;
  }
  keyframes_.erase(keyframes_.begin());
  slots_.erase(slots_.begin());
}

void PoseWindow::explore(size_t j, std::vector<Eigen::Vector2i>& extra) {
  const cv::Mat& usable = slots_[j].usable;
  int tries = 0;
  const int want = static_cast<int>(extra.size()) + params_.explore_pixels;
  while (static_cast<int>(extra.size()) < want && tries++ < 8 * std::max(1, params_.explore_pixels)) {
    const int u = 1 + static_cast<int>(nextRandom(rng_state_) % static_cast<uint64_t>(std::max(1, usable.cols - 2)));
    const int v = 1 + static_cast<int>(nextRandom(rng_state_) % static_cast<uint64_t>(std::max(1, usable.rows - 2)));
    if (usable.at<uint8_t>(v, u)) extra.emplace_back(u, v);
  }
}

void PoseWindow::castBase(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps, KfEval& e) const {
  auto hits = std::make_shared<std::vector<CachedHit>>();
  e.base = linearizeSamples(j, T_world_kf, maps, slots_[j].base_samples, nullptr, hits.get());
  e.base_hits = std::move(hits);
}

void PoseWindow::castExtra(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps, KfEval& e) const {
  auto hits = std::make_shared<std::vector<CachedHit>>();
  e.extra = linearizeSamples(j, T_world_kf, maps, slots_[j].extra_samples, &e.extra_pixels, hits.get());
  e.extra_hits = std::move(hits);
}

PoseWindow::KfEval PoseWindow::onPlanes(size_t j, const Eigen::Isometry3d& T_world_kf, const KfEval& from) const {
  static const std::vector<CachedHit> kNone;
  KfEval e;
  e.base = linearizeCached(j, T_world_kf, slots_[j].base_samples, from.base_hits ? *from.base_hits : kNone, nullptr);
  e.extra = linearizeCached(j, T_world_kf, slots_[j].extra_samples, from.extra_hits ? *from.extra_hits : kNone,
                            &e.extra_pixels);
  e.base_hits = from.base_hits;
  e.extra_hits = from.extra_hits;
  return e;
}

double PoseWindow::assemble(const std::vector<Eigen::Isometry3d>& x, const std::vector<KfEval>& ev, Eigen::MatrixXd* H,
                            Eigen::VectorXd* b, ChannelStats& stats) const {
  const size_t n = keyframes_.size();
  const int dim = static_cast<int>(6 * n);
  stats = ChannelStats{};
  double cost = 0;
  if (H) {
    H->setZero(dim, dim);
    b->setZero(dim);
  }
  for (size_t j = 0; j < n; ++j) {
    for (const Linearization* L : {&ev[j].base, &ev[j].extra}) {
      cost += L->cost;
      stats.photo_explicit += L->counts.photo_explicit;
      stats.depth_explicit += L->counts.depth_explicit;
      stats.photo_implicit += L->counts.photo_implicit;
      stats.depth_implicit += L->counts.depth_implicit;
      if (H) {
        H->block<6, 6>(static_cast<int>(6 * j), static_cast<int>(6 * j)) += L->H;
        b->segment<6>(static_cast<int>(6 * j)) += L->b;
      }
    }
  }
  for (size_t j = 0; j + 1 < n; ++j) {
    Eigen::Matrix<double, 12, 12> Hr;
    Eigen::Matrix<double, 12, 1> br;
    const double c = relativeFactor(j, x[j], x[j + 1], H ? &Hr : nullptr, H ? &br : nullptr);
    cost += c;
    if (H) {
      const int o = static_cast<int>(6 * j);
      H->block<12, 12>(o, o) += Hr;
      b->segment<12>(o) += br;
    }
  }
  Matrix6d Hp;
  Vector6d bp;
  cost += priorCost(x[0], H ? &Hp : nullptr, H ? &bp : nullptr);
  if (H && has_prior_) {
    H->block<6, 6>(0, 0) += Hp;
    b->segment<6>(0) += bp;
  }
  stats.cost = cost;
  return cost;
}

double PoseWindow::baseCost(const std::vector<Eigen::Isometry3d>& x, const std::vector<KfEval>& ev) const {
  const size_t n = keyframes_.size();
  double c = 0;
  for (size_t j = 0; j < n; ++j) c += ev[j].base.cost;
  for (size_t j = 0; j + 1 < n; ++j) c += relativeFactor(j, x[j], x[j + 1], nullptr, nullptr);
  return c + priorCost(x[0], nullptr, nullptr);
}

bool PoseWindow::nextPixelSets(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps, bool recast,
                               KfEval& e) {
  Slot& s = slots_[j];
  std::vector<size_t> order(s.extra_samples.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = k;
  const size_t keep = std::min(order.size(), static_cast<size_t>(std::max(0, params_.top_pixels)));
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(keep), order.end(),
                    [&](size_t a, size_t c) { return e.extra_pixels[a].residual > e.extra_pixels[c].residual; });
  std::vector<Eigen::Vector2i> next;
  std::vector<size_t> kept;  // old extra index of each top pixel
  for (size_t k = 0; k < keep; ++k) {
    const PixelSample& px = s.extra_samples[order[k]];
    if (e.extra_pixels[order[k]].residual > 0) {
      next.emplace_back(px.u, px.v);
      kept.push_back(order[k]);
    }
  }
  const size_t n_top = next.size();
  s.extra = std::move(next);
  explore(j, s.extra);
  s.extra_samples = gather(j, s.extra);
  if (recast) {
    castBase(j, T_world_kf, maps, e);
    castExtra(j, T_world_kf, maps, e);
    return true;
  }
  // Between casts the top pixels keep their hits: only the explore pixels
  // are cast.
  auto hits = std::make_shared<std::vector<CachedHit>>();
  if (e.extra_hits) {
    std::vector<int> new_index(e.extra_pixels.size(), -1);
    for (size_t k = 0; k < n_top && k < s.extra_samples.size(); ++k) new_index[kept[k]] = static_cast<int>(k);
    for (const CachedHit& h : *e.extra_hits) {
      if (h.sample < new_index.size() && new_index[h.sample] >= 0) {
        hits->push_back(h);
        hits->back().sample = static_cast<uint32_t>(new_index[h.sample]);
      }
    }
  }
  const std::vector<PixelSample> fresh(
      s.extra_samples.begin() + static_cast<std::ptrdiff_t>(std::min(n_top, s.extra_samples.size())),
      s.extra_samples.end());
  std::vector<CachedHit> fresh_hits;
  linearizeSamples(j, T_world_kf, maps, fresh, nullptr, &fresh_hits);
  for (CachedHit& h : fresh_hits) {
    h.sample += static_cast<uint32_t>(n_top);
    hits->push_back(h);
  }
  e.extra = linearizeCached(j, T_world_kf, s.extra_samples, *hits, &e.extra_pixels);
  e.extra_hits = std::move(hits);
  return false;
}

std::vector<Matrix6d> PoseWindow::marginalInformation(const Eigen::MatrixXd& H) const {
  const int dim = static_cast<int>(H.rows());
  Eigen::MatrixXd Hr = H;
  for (int k = 0; k < dim; ++k) Hr(k, k) += 1e-9 * std::max(1.0, Hr(k, k));
  const Eigen::MatrixXd cov = Hr.ldlt().solve(Eigen::MatrixXd::Identity(dim, dim));
  std::vector<Matrix6d> info;
  for (int j = 0; 6 * j < dim; ++j) {
    const Matrix6d S = cov.block<6, 6>(6 * j, 6 * j);
    info.push_back(S.allFinite() ? Matrix6d(S.ldlt().solve(Matrix6d::Identity())) : Matrix6d::Zero());
  }
  return info;
}

SolveReport PoseWindow::solve(const FeedbackMaps& maps, const std::function<bool()>& stop) {
  SolveReport rep;
  const size_t n = keyframes_.size();
  for (const auto& kf : keyframes_) rep.poses_before.push_back(kf.T_world_cam);
  if (n == 0 || !maps.tsdf) {
    rep.failure = n == 0 ? "empty window" : "no map";
    return rep;
  }
  const FeedbackParams& p = params_;
  const int dim = static_cast<int>(6 * n);
  // Fresh extra pixels: the previous top set plus a uniform explore set.
  for (size_t j = 0; j < n; ++j) {
    slots_[j].extra.clear();
    explore(j, slots_[j].extra);
    slots_[j].extra_samples = gather(j, slots_[j].extra);
  }
  // The caller's stop is asked before each keyframe's cast and each step
  // (the slices a scheduler admits); once it says stop, the solve keeps the
  // last accepted poses.
  auto halted = [&] {
    if (!rep.stopped && stop && stop()) rep.stopped = true;
    return rep.stopped;
  };
  std::vector<Eigen::Isometry3d> x(n);
  for (size_t j = 0; j < n; ++j) x[j] = keyframes_[j].T_world_cam;
  // A keyframe of the previous solve starts on that solve's last planes for
  // its base pixels (7 of 8 keyframes were just solved against nearly the
  // same map); its extras and a new keyframe are cast.
  std::vector<KfEval> ev(n);
  for (size_t j = 0; j < n; ++j) {
    if (halted()) return rep;
    if (p.reuse_planes && slots_[j].base_hits) {
      ev[j].base = linearizeCached(j, x[j], slots_[j].base_samples, *slots_[j].base_hits, nullptr);
      ev[j].base_hits = slots_[j].base_hits;
    } else {
      castBase(j, x[j], maps, ev[j]);
      ++rep.evaluations;
    }
    castExtra(j, x[j], maps, ev[j]);
  }
  Eigen::MatrixXd H;
  Eigen::VectorXd b;
  double cost = assemble(x, ev, &H, &b, rep.before);
  rep.after = rep.before;
  rep.base_cost_before = rep.base_cost_after = baseCost(x, ev);
  double mu = p.lm_initial_damping;
  // Trial steps are judged, and the next step linearized, on the tangent
  // planes of the last cast; rays are cast again every relinearize_every
  // accepted steps (casting at every trial was 80 % of the solve).
  int since_cast = 0;
  const int recast_every = std::max(1, p.relinearize_every);
  for (int it = 0; it < p.iterations && !halted(); ++it) {
    ++rep.iterations;
    Eigen::MatrixXd A = H;
    for (int k = 0; k < dim; ++k) A(k, k) += mu * std::max(H(k, k), 1e-6) + 1e-9;
    const Eigen::VectorXd delta = A.ldlt().solve(-b);
    if (!delta.allFinite()) break;
    std::vector<Eigen::Isometry3d> x_try(n);
    for (size_t j = 0; j < n; ++j) x_try[j] = x[j] * expSE3(delta.segment<6>(static_cast<int>(6 * j)));
    std::vector<KfEval> ev_try(n);
    for (size_t j = 0; j < n; ++j) ev_try[j] = onPlanes(j, x_try[j], ev[j]);
    ChannelStats st;
    if (!(assemble(x_try, ev_try, nullptr, nullptr, st) < cost)) {  // NaN refused too
      mu *= 4.0;
      continue;
    }
    ++rep.accepted;
    x = x_try;
    ev = std::move(ev_try);
    mu = std::max(mu / 3.0, 1e-9);
    const bool converged = delta.lpNorm<Eigen::Infinity>() < 1e-7;
    if (it + 1 < p.iterations && !converged) {
      // Omega for the next iteration, cast at the accepted poses.
      const bool recast = ++since_cast >= recast_every;
      for (size_t j = 0; j < n && !halted(); ++j) {
        if (nextPixelSets(j, x[j], maps, recast, ev[j])) ++rep.evaluations;
      }
      if (recast) since_cast = 0;
      // Stopped: x is accepted, and each keyframe's evaluation (new pixel
      // set or old) is at x, so the report below is consistent.
      if (rep.stopped) break;
    }
    cost = assemble(x, ev, &H, &b, st);
    if (converged) break;
  }
  for (size_t j = 0; j < n; ++j) {
    keyframes_[j].T_world_cam = x[j];
    slots_[j].base_hits = ev[j].base_hits;
  }
  rep.marginal_information = marginalInformation(H);
  assemble(x, ev, nullptr, nullptr, rep.after);  // ev is the evaluation at x
  rep.base_cost_after = baseCost(x, ev);
  // Before and after on the same planes (the last cast's), so that the
  // comparison is of poses, not of casts.
  static const std::vector<CachedHit> kNone;
  std::vector<KfEval> start(n);
  for (size_t j = 0; j < n; ++j) {
    start[j].base = linearizeCached(j, rep.poses_before[j], slots_[j].base_samples,
                                    ev[j].base_hits ? *ev[j].base_hits : kNone, nullptr);
    rep.channels_agree.push_back(ev[j].base.depth_cost <= start[j].base.depth_cost &&
                                 ev[j].base.photo_cost <= start[j].base.photo_cost);
  }
  rep.base_cost_before = baseCost(rep.poses_before, start);
  return rep;
}

}  // namespace hxmap::alg
