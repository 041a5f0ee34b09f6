#include "hxmap/implicit/refine.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

namespace {

constexpr float kBeta1 = 0.9f, kBeta2 = 0.999f, kEps = 1e-8f;

// Adam on parameters i .. i + N - 1: P -= lr m_hat / (sqrt(v_hat) + eps)
// with m_hat = m / c1 and v_hat = v / c2, the bias corrections folded into
// step = lr / c1 and inv_sqrt_c2 = 1 / sqrt(c2); the gradient is reset.
template <int N>
HXMAP_INLINE_IN_CLONES void adamStep(float* p, float* m, float* v, float* g, size_t i, float step, float inv_sqrt_c2) {
  for (int k = 0; k < N; ++k) {
    const size_t j = i + static_cast<size_t>(k);
    m[j] = kBeta1 * m[j] + (1.0f - kBeta1) * g[j];
    v[j] = kBeta2 * v[j] + (1.0f - kBeta2) * g[j] * g[j];
    p[j] -= step * m[j] / (std::sqrt(v[j]) * inv_sqrt_c2 + kEps);
    g[j] = 0.0f;
  }
}

}  // namespace

RoiRefiner::RoiRefiner(const TsdfMap& map, const Eigen::AlignedBox3f& box_world,
                       const std::vector<KeyframeImages>& keyframes, const ImplicitParams& params)
    : params_(params), rng_(params.seed * 0x9E3779B97F4A7C15ULL + 7) {
  const float vs = map.voxelSize();
  const Eigen::Vector3i vmin = map.voxelOf(box_world.min() + Eigen::Vector3f::Constant(0.5f * vs));
  const Eigen::Vector3i vmax = map.voxelOf(box_world.max() - Eigen::Vector3f::Constant(0.5f * vs));
  const Eigen::Vector3i count = (vmax - vmin + Eigen::Vector3i::Ones()).cwiseMax(2);
  field_ = NeuralField(map, vmin, count, params_);

  snapshot_weight_.assign(static_cast<size_t>(count.x()) * count.y() * count.z(), 0.0f);
  snapshot_sdf_.assign(snapshot_weight_.size(), 0.0f);
  surface_offset_.assign(snapshot_weight_.size(), Eigen::Vector3f::Zero());
  snapshot_updates_.assign(snapshot_weight_.size(), 0);
  for (int z = 0; z < count.z(); ++z) {
    for (int y = 0; y < count.y(); ++y) {
      for (int x = 0; x < count.x(); ++x) {
        Voxel v;
        if (map.voxel(vmin + Eigen::Vector3i(x, y, z), v)) {
          const size_t node = (static_cast<size_t>(z) * count.y() + y) * count.x() + x;
          snapshot_weight_[node] = v.weight;
          snapshot_sdf_[node] = std::clamp(v.sdf_m, -map.truncation(), map.truncation());
          snapshot_updates_[node] = v.stats.updates;
          // Where the voxel's nearest surface is (for the bias lookup): the
          // center moved by its distance against the normal.
          const float* g = &field_.parameters()[node * NeuralField::kCoarseStride];
          surface_offset_[node] = -v.sdf_m * Eigen::Vector3f(g[1], g[2], g[3]);
        }
      }
    }
  }
  // DESIGN: the rays whose surface lies in the box constrain the field
  // where the keyframes saw surface; what fusion got wrong by growing
  // surface where some view saw through (the negative shadow behind a thin
  // rod, up to mu deep) only rays that cross the box to a surface beyond
  // it can clear. Of those, the ones that pass a voxel the snapshot holds
  // clearly inside a surface (below -half a voxel) are kept: elsewhere
  // they agree with the field and teach it nothing.
  const float vs_m = map.voxelSize();
  const float margin_m = 2.0f * static_cast<float>(params_.sample_band_voxels) * vs_m;
  auto crossesSnapshotSurface = [&](const TrainingRay& r) {
    if (r.t_obs < r.t_out + margin_m) return false;
    const Eigen::Vector3f lo = field_.box().min();
    for (float t = r.t_in; t <= r.t_out; t += 0.5f * vs_m) {
      const Eigen::Vector3f q = (r.origin + t * r.dir - lo) / vs_m + Eigen::Vector3f::Constant(0.5f);
      const int x = floorToInt(q.x()), y = floorToInt(q.y()), z = floorToInt(q.z());
      if (x < 0 || y < 0 || z < 0 || x >= count.x() || y >= count.y() || z >= count.z()) continue;
      const size_t node = (static_cast<size_t>(z) * count.y() + y) * count.x() + x;
      if (snapshot_weight_[node] > 0.0f && snapshot_sdf_[node] < -0.5f * vs_m) return true;
    }
    return false;
  };
  rays_ = collectRays(keyframes, field_.box(), params_, crossesSnapshotSurface);
  for (const TrainingRay& r : rays_) stats_.free_space_rays += r.free_space;
  std::vector<int32_t> surface_rays;
  for (size_t i = 0; i < rays_.size(); ++i) {
    if (!rays_[i].free_space) surface_rays.push_back(static_cast<int32_t>(i));
  }
  const size_t n_eval = std::min<size_t>(surface_rays.size(), 256);
  for (size_t i = 0; i < n_eval; ++i) eval_rays_.push_back(surface_rays[i * surface_rays.size() / n_eval]);

  const size_t np = field_.parameters().size();
  grad_.assign(np, 0.0f);
  m_.assign(np, 0.0f);
  v_.assign(np, 0.0f);
  seen_.assign(field_.coarseGrid().nodeCount(), 0);
  stats_.rays = rays_.size();
  stats_.parameters = np;
  stats_.memory_bytes = 4 * np * sizeof(float) + field_.nodeCount() * sizeof(uint32_t) + seen_.size() +
                        rays_.size() * sizeof(TrainingRay) +
                        snapshot_weight_.size() * (3 * sizeof(float) + sizeof(Eigen::Vector3f));
  const Eigen::Vector3i nv = field_.voxelCount();
  cell_dims_ = (nv + Eigen::Vector3i::Constant(kCellVoxels - 1)) / kCellVoxels;
  cells_.assign(static_cast<size_t>(cell_dims_.x()) * cell_dims_.y() * cell_dims_.z(), {});
  const size_t m = std::min<size_t>(rays_.size(), static_cast<size_t>(std::max(1, params_.bias_rays)));
  for (size_t i = 0; i < m; ++i) bias_rays_.push_back(static_cast<int32_t>(i * rays_.size() / m));
  finished_ = rays_.empty();
}

bool RoiRefiner::prepareStep() {
  // DESIGN: measuring the TSDF (its depth error and its bias per cell)
  // renders a few thousand rays; done in steps of kPrepareRays so that no
  // slice of a job costs much more than a training iteration and the
  // scheduler can fit it into a frame's slack.
  if (prepared_) return true;
  if (!measured_before_) {
    stats_.depth_l1_before_m = evalDepthL1(nullptr);
    stats_.depth_l1_after_m = stats_.depth_l1_before_m;
    measured_before_ = true;
  } else {
    const size_t end = std::min(bias_rays_.size(), prep_next_ + kPrepareRays);
    measureTsdfBias(std::vector<int32_t>(bias_rays_.begin() + static_cast<std::ptrdiff_t>(prep_next_),
                                         bias_rays_.begin() + static_cast<std::ptrdiff_t>(end)));
    prep_next_ = end;
  }
  prepared_ = measured_before_ && prep_next_ >= bias_rays_.size();
  return prepared_;
}

void RoiRefiner::measureTsdfBias(const std::vector<int32_t>& which) {
  // The untrained field is the TSDF: render an even spread of the rays and
  // pool each cell's residuals D_tsdf - t_obs.
  if (which.empty()) return;
  Rendering rendering;
  const RenderBatch b = renderRays(which, rendering);
  for (size_t i = 0; i < b.rays.size(); ++i) {
    const TrainingRay& r = rays_[static_cast<size_t>(b.rays[i])];
    // Binned where the TSDF renders the surface (where it has one): binning
    // by the observed point would sort rays by their noise (the rays whose
    // noise carries them across a cell border all err the same way).
    const float t_far = b.t[(i + 1) * static_cast<size_t>(b.samples) - 1];
    const bool rendered = rendering.depth[i] < t_far;
    // A free-space ray tells of the TSDF's surface where it renders one
    // (a bias: surface where a view saw through).
    if (r.free_space && !rendered) continue;
    const float t_bin = rendered ? rendering.depth[i] : r.t_obs;
    Cell& cell = cells_[cellIndex(r.origin + t_bin * r.dir)];
    const double e = rendering.depth[i] - (r.free_space ? t_far : r.t_obs);
    cell.sum += e;
    cell.sum_sq += e * e;
    ++cell.rays;
    cell.keyframes |= uint64_t{1} << (r.keyframe % 64);
    if (!r.free_space) {
      Cell& at_obs = cells_[cellIndex(r.origin + r.t_obs * r.dir)];
      at_obs.tsdf_abs += std::abs(rendering.depth[i] - r.t_obs);
      ++at_obs.tsdf_abs_rays;
    }
  }
}

size_t RoiRefiner::cellIndex(const Eigen::Vector3f& p_world) const {
  return cellOf((p_world - field_.box().min()) / field_.voxelSize() + Eigen::Vector3f::Constant(0.5f));
}

size_t RoiRefiner::cellOf(const Eigen::Vector3f& q) const {
  Eigen::Vector3i c;
  for (int a = 0; a < 3; ++a) c[a] = std::clamp(floorToInt(q[a]) / kCellVoxels, 0, cell_dims_[a] - 1);
  return (static_cast<size_t>(c.z()) * cell_dims_.y() + c.y()) * cell_dims_.x() + c.x();
}

float RoiRefiner::writebackRatio(int x, int y, int z) const {
  // Inverse-variance blending of two estimates of the voxel's distance: the
  // TSDF's, with variance sigma^2 / n + b^2 (noise averaged over the n
  // frames fused, plus a bias b averaging cannot remove), and the field's.
  // Where the TSDF is biased the field, trained on K keyframes, averages
  // their noise to sigma^2 / K; where it is not, the field's fine grid fits
  // the rays it sees (half a voxel apart, hundreds of rays per cell) and
  // counts as one observation, sigma^2. sigma^2 and b^2 come from the cell's
  // residuals (spread and squared mean, less kBiasZ2 times the mean's own
  // variance). The field's weight relative to the TSDF's is then
  // 1 / n + K b^2 / sigma^2, capped at writeback_weight_ratio. (With K / n
  // for the first term, a noisy wall patch's precision at 1 cm voxels fell
  // from 96 % to 89 %; 91 % with 1 / n.)
  const auto cap = static_cast<float>(params_.writeback_weight_ratio);
  const Eigen::Vector3i n_vox = field_.voxelCount();
  const Eigen::Vector3f at =
      Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)) +
      surface_offset_[(static_cast<size_t>(z) * n_vox.y() + y) * n_vox.x() + x] / field_.voxelSize() +
      Eigen::Vector3f::Constant(0.5f);
  const Cell& c = cells_[cellOf(at)];
  // DESIGN: no write-back where the field renders the keyframes no better
  // than the TSDF did (mean |rendered - observed| depth of the rays whose
  // surface lies in the cell: the TSDF's before training, the field's over
  // its recent training batches, weighted by kFieldErrorDecay per
  // iteration). On the noise-free Replica slice the TSDF renders within
  // half a millimetre, and fields that did not reach that were blended in
  // where a sub-millimetre offset counted as bias: the map's rendering
  // inside the ROIs went 0.37 -> 0.43 mm median after write-back, now
  // 0.37 -> 0.39 mm; the quality room's figures did not move beyond their
  // run-to-run spread. Requiring the evidence (cells with fewer rays not
  // written at all) cost half the rods' recall gain at 2 cm.
  if (c.field_w >= kMinCellRays && c.tsdf_abs_rays >= kMinCellRays &&
      c.field_abs / c.field_w >= c.tsdf_abs / c.tsdf_abs_rays) {
    return 0.0f;
  }
  // n counts observations: the in-band updates, or the fused weight where
  // that is larger (a weight sums per-pixel confidences, low for far or
  // noisy depth; updates leave out the clamped free-space observations of
  // voxels about mu from the surface). Both are lower bounds.
  const size_t v = (static_cast<size_t>(z) * n_vox.y() + y) * n_vox.x() + x;
  const float n = std::max({static_cast<float>(snapshot_updates_[v]), snapshot_weight_[v], 1.0f});
  // Without evidence of a bias (too few rays, or one keyframe: a bias seen
  // from one keyframe is indistinguishable from its own error) the field
  // counts as one keyframe's worth.
  const int keyframes = __builtin_popcountll(c.keyframes);
  if (c.rays < kMinCellRays || keyframes < 2) return std::min(cap, 1.0f / n);
  const double mean = c.sum / c.rays;
  const double floor = 0.1 * field_.voxelSize();
  const double var = std::max(c.sum_sq / c.rays - mean * mean, floor * floor);
  const double bias_sq = std::max(0.0, mean * mean - kBiasZ2 * var / c.rays);
  const auto K = static_cast<double>(keyframes);
  return std::min(cap, static_cast<float>(1.0 / n + K * bias_sq / var));
}

bool RoiRefiner::completes(int x, int y, int z) const {
  // DESIGN: completion. Fusion never took an observation for some voxels
  // the keyframes did see: depth at an incidence past
  // preprocess.max_incidence_deg has no confidence (a shelf's top seen
  // only at a grazing angle: in the quality room at half size and 1 cm
  // voxels, 70 % of it stayed empty), and the blocks behind them were
  // never allocated. The field, trained on those keyframes' rays, has the
  // surface there. It is written back where the cell's rays render better
  // from the field than from the TSDF (writebackRatio's test, with the
  // evidence required: kMinCellRays of both), at kCompletionWeight: one
  // good observation's worth, so fusion outweighs it after a frame or two
  // that see the voxel at a usable angle.
  const Eigen::Vector3f at = Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)) +
                             Eigen::Vector3f::Constant(0.5f);
  const Cell& c = cells_[cellOf(at)];
  return c.field_w >= kMinCellRays && c.tsdf_abs_rays >= kMinCellRays &&
         c.field_abs / c.field_w < c.tsdf_abs / c.tsdf_abs_rays;
}

RenderBatch RoiRefiner::renderRays(const std::vector<int32_t>& which, Rendering& rendering) const {
  ImplicitParams p = params_;
  p.regularizer_points = 0;
  uint64_t rng = 1;  // unused: no jitter, no random rays or points
  RenderBatch b = sampleBatch(field_, rays_, which, p, false, rng, nullptr, &cache_);
  evaluateLoss(field_, rays_, b, p, nullptr, nullptr, &rendering, nullptr, &cache_);
  return b;
}

double RoiRefiner::evalDepthL1(std::vector<float>* per_ray) const {
  if (eval_rays_.empty()) return 0.0;
  Rendering rendering;
  const RenderBatch b = renderRays(eval_rays_, rendering);
  double sum = 0;
  for (size_t i = 0; i < b.rays.size(); ++i) {
    sum += std::abs(rendering.depth[i] - rays_[static_cast<size_t>(b.rays[i])].t_obs);
  }
  if (per_ray) *per_ray = std::move(rendering.depth);
  return sum / static_cast<double>(b.rays.size());
}

void RoiRefiner::markSeen(const RenderBatch& batch) {
  // Voxels around samples that light still reaches (in front of the first
  // surface or at it): what the renderings constrain.
  const int N = batch.samples;
  for (size_t i = 0; i < batch.rays.size(); ++i) {
    const TrainingRay& r = rays_[static_cast<size_t>(batch.rays[i])];
    const uint8_t mark = r.free_space ? kSeen | kSeenThrough : kSeen;
    for (int k = 0; k < N; ++k) {
      const size_t j = i * static_cast<size_t>(N) + static_cast<size_t>(k);
      if (rendering_.transmittance[j] < kSeenTransmittance) break;
      const Corners& c = cache_.coarse[j];  // the sample's, from the batch's forward pass
      for (int q = 0; q < 8; ++q) {
        if (c.weight[q] > 0.0f) seen_[static_cast<size_t>(c.node[q])] |= mark;
      }
    }
  }
}

bool RoiRefiner::iterate(int n) {
  std::vector<float>& P = field_.parameters();
  const size_t grid_end = field_.gridParameters();
  const size_t coarse_nodes = field_.coarseGrid().nodeCount();
  if (!finished_ && !prepared_) {  // a preparation step takes the place of this call's iterations
    enterPhase(probe_, RefinePhase::kPrepare);
    prepareStep();
    enterPhase(probe_, RefinePhase::kOutside);
    return !finished_;
  }
  for (int it = 0; it < n && !finished_; ++it) {
    enterPhase(probe_, RefinePhase::kSample);
    const RenderBatch batch = sampleBatch(field_, rays_, {}, params_, true, rng_, probe_, &cache_);
    touched_.begin(field_.nodeCount());
    const LossTerms L = evaluateLoss(field_, rays_, batch, params_, &grad_, &touched_, &rendering_, probe_, &cache_);
    enterPhase(probe_, RefinePhase::kBookkeeping);
    markSeen(batch);
    for (Cell& c : cells_) {
      c.field_abs *= kFieldErrorDecay;
      c.field_w *= kFieldErrorDecay;
    }
    for (size_t i = 0; i < batch.rays.size(); ++i) {
      const TrainingRay& r = rays_[static_cast<size_t>(batch.rays[i])];
      if (r.free_space) continue;
      Cell& c = cells_[cellIndex(r.origin + r.t_obs * r.dir)];
      c.field_abs += std::abs(rendering_.depth[i] - r.t_obs);
      c.field_w += 1.0;
    }
    if (stats_.iterations == 0) stats_.first = L;
    stats_.last = L;
    const int t = ++stats_.iterations;
    const float c1 = 1.0f - std::pow(kBeta1, static_cast<float>(t)),
                c2 = 1.0f - std::pow(kBeta2, static_cast<float>(t));
    const float inv_sqrt_c2 = 1.0f / std::sqrt(c2);
    enterPhase(probe_, RefinePhase::kOptimizer);
    const auto step_grid = static_cast<float>(params_.learning_rate_grid) / c1;
    const auto step_mlp = static_cast<float>(params_.learning_rate_mlp) / c1;
    float* p = P.data();
    float* g = grad_.data();
    float* m = m_.data();
    float* v = v_.data();
    const size_t fine = field_.fineOffset();
    // A coarse node's 8 floats in one step (its unused eighth has no
    // gradient and stays 0).
    dispatchAvx2Fma([&]() HXMAP_LAMBDA_INLINE_IN_CLONES {
      for (int32_t node : touched_.nodes()) {  // lazy: only the grid nodes this batch touched
        if (static_cast<size_t>(node) < coarse_nodes) {
          adamStep<NeuralField::kCoarseStride>(p, m, v, g, static_cast<size_t>(node) * NeuralField::kCoarseStride,
                                               step_grid, inv_sqrt_c2);
        } else {
          adamStep<1>(p, m, v, g, fine + (static_cast<size_t>(node) - coarse_nodes), step_grid, inv_sqrt_c2);
        }
      }
      for (size_t i = grid_end; i < P.size(); ++i) adamStep<1>(p, m, v, g, i, step_mlp, inv_sqrt_c2);
    });
    enterPhase(probe_, RefinePhase::kBookkeeping);

    const double prev = smoothed_loss_.empty() ? L.total : smoothed_loss_.back();
    smoothed_loss_.push_back(smoothed_loss_.empty() ? L.total : 0.9 * prev + 0.1 * L.total);
    const auto k = static_cast<size_t>(std::max(1, params_.patience));
    if (smoothed_loss_.size() > k &&
        smoothed_loss_.back() > smoothed_loss_[smoothed_loss_.size() - 1 - k] * (1.0 - params_.convergence_rel)) {
      stats_.converged = true;
      finished_ = true;
    }
    if (t >= params_.iterations) finished_ = true;
  }
  enterPhase(probe_, RefinePhase::kOutside);
  return !finished_;
}

RefineResult RoiRefiner::result() {
  enterPhase(probe_, RefinePhase::kPrepare);
  while (!rays_.empty() && !prepareStep()) {
  }
  enterPhase(probe_, RefinePhase::kWriteBack);
  RefineResult out;
  out.stats = stats_;
  std::vector<float> rendered;
  out.stats.depth_l1_after_m = evalDepthL1(&rendered);

  // sigma_Neural per block, from the rays' depth errors.
  const float vs = field_.voxelSize(), block = vs * kBlockSide;
  std::unordered_map<uint64_t, std::pair<double, int>> per_block;
  for (size_t i = 0; i < rendered.size(); ++i) {
    const TrainingRay& r = rays_[static_cast<size_t>(eval_rays_[i])];
    const Eigen::Vector3f p = r.origin + r.t_obs * r.dir;
    const BlockKey key(floorToInt(p.x() / block), floorToInt(p.y() / block), floorToInt(p.z() / block));
    auto& acc = per_block[packBlockKey(key)];
    const double e = rendered[i] - r.t_obs;
    acc.first += e * e;
    ++acc.second;
  }
  for (const auto& [k, acc] : per_block) {
    out.neural_sigma.emplace_back(unpackBlockKey(k), static_cast<float>(std::sqrt(acc.first / acc.second)));
  }
  std::sort(out.neural_sigma.begin(), out.neural_sigma.end(),
            [](const auto& a, const auto& b) { return packBlockKey(a.first) < packBlockKey(b.first); });

  // Write-back (eq 11) of the voxels the snapshot had observed.
  const Eigen::Vector3i n = field_.voxelCount(), vmin = field_.voxelMin();
  const float mu = field_.truncation();
  const float ramp = static_cast<float>(std::max(1e-3, params_.border_blend_voxels));
  std::vector<Eigen::Vector3i> voxels;
  std::vector<float> weights;
  std::vector<size_t> nodes;
  // Where a free-space ray saw through a voxel the snapshot holds inside:
  // the field's largest share there (see below), else 0.
  std::vector<float> through_ratios;
  // For the detail layer: the field's share of each written-back voxel.
  std::vector<float> share(snapshot_weight_.size(), 0.0f);
  for (int z = 0; z < n.z(); ++z) {
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x) {
        const size_t node = (static_cast<size_t>(z) * n.y() + y) * n.x() + x;
        const float w0 = snapshot_weight_[node];
        // Only voxels the renderings saw (a sample with light still reaching
        // it): elsewhere nothing constrained the field (the decoder is
        // shared across the box and drifts where no ray looks, e.g. behind
        // a surface).
        if (!seen_[node]) continue;
        const int d = std::min({x, y, z, n.x() - 1 - x, n.y() - 1 - y, n.z() - 1 - z});
        const float blend = std::min(1.0f, static_cast<float>(d) / ramp);
        if (blend <= 0.0f) continue;
        if (!(w0 > 0.0f)) {  // never fused: completion (below), where the field did better
          if (!params_.completion || !completes(x, y, z)) continue;
          voxels.push_back(vmin + Eigen::Vector3i(x, y, z));
          weights.push_back(kCompletionWeight * blend);
          nodes.push_back(node);
          through_ratios.push_back(0.0f);
          share[node] = blend;
          continue;
        }
        const float ratio = writebackRatio(x, y, z) * blend;
        const bool through = (seen_[node] & kSeenThrough) && snapshot_sdf_[node] < 0.0f;
        if (!(ratio > 0.0f) && !through) continue;
        voxels.push_back(vmin + Eigen::Vector3i(x, y, z));
        weights.push_back(ratio * w0);
        nodes.push_back(node);
        through_ratios.push_back(through ? static_cast<float>(params_.writeback_weight_ratio) * blend : 0.0f);
        share[node] = ratio / (1.0f + ratio);
      }
    }
  }
  constexpr size_t kChunk = 4096;
  out.patch.entries.reserve(voxels.size());
  for (size_t c0 = 0; c0 < voxels.size(); c0 += kChunk) {
    const size_t c1 = std::min(voxels.size(), c0 + kChunk);
    Eigen::Matrix3Xf pts(3, static_cast<Eigen::Index>(c1 - c0));
    for (size_t i = c0; i < c1; ++i) {
      pts.col(static_cast<Eigen::Index>(i - c0)) = (voxels[i].cast<float>() + Eigen::Vector3f::Constant(0.5f)) * vs;
    }
    Eigen::VectorXf s;
    Eigen::Matrix3Xf rgb;
    field_.forward(pts, s, &rgb, nullptr);
    for (size_t i = c0; i < c1; ++i) {
      const auto j = static_cast<Eigen::Index>(i - c0);
      TsdfPatch::Entry e;
      e.voxel = voxels[i];
      e.sdf_m = std::clamp(s[j], -mu, mu);
      e.weight = weights[i];
      // DESIGN: a voxel the snapshot holds inside a surface, where the
      // field, trained on views whose light passed through it, found free
      // space: fusion averaged the views that saw it behind a surface (a
      // thin rod's shadow, up to mu deep) with the fewer that saw through,
      // and the views that saw through are right. The field takes the
      // largest share there, whatever the cell's bias statistics (measured
      // on the surface the box's own rays see) say. Before, the field
      // cleared 130 of a rod's 169 shadow voxels and 18 stayed cleared
      // after the blend.
      const size_t node = nodes[i];
      if (through_ratios[i] > 0.0f && e.sdf_m > 0.0f) {
        const float ratio = through_ratios[i];
        e.weight = std::max(e.weight, ratio * snapshot_weight_[node]);
        e.seen_through = true;
        share[node] = std::max(share[node], ratio / (1.0f + ratio));
      }
      if (!(e.weight > 0.0f)) continue;  // the field did no better here
      // A voxel completed in open space adds nothing but a block to hold it.
      if (!(snapshot_weight_[node] > 0.0f) && !(std::abs(e.sdf_m) < mu)) continue;
      for (int a = 0; a < 3; ++a) e.rgb[a] = static_cast<uint8_t>(std::clamp(rgb(a, j), 0.0f, 1.0f) * 255.0f + 0.5f);
      e.has_color = true;
      out.patch.entries.push_back(e);
      out.stats.completed += !(snapshot_weight_[node] > 0.0f);
    }
  }
  out.stats.patch_entries = out.patch.entries.size();
  out.detail = makeDetail(share);
  out.stats.detail_nodes = out.detail ? out.detail->detailed_nodes : 0;
  enterPhase(probe_, RefinePhase::kOutside);
  return out;
}

std::shared_ptr<const RefinedDetail> RoiRefiner::makeDetail(const std::vector<float>& share) const {
  // Fine nodes whose 8 voxel centers the snapshot observed, where the
  // field's share reaches detail_min_share and the snapshot's surface is
  // within two voxels (farther, no zero crossing can move). Where the share
  // is lower the TSDF's error was noise: the field, fit to a few keyframes,
  // would only add their noise below the voxel size.
  const auto min_share = static_cast<float>(params_.detail_min_share);
  if (min_share >= 1.0f) return nullptr;
  const GridLayout& coarse = field_.coarseGrid();
  auto detail = std::make_shared<RefinedDetail>();
  detail->grid = field_.fineGrid();
  detail->grid.channels = 1;
  detail->box = field_.box();
  detail->refined_m.assign(detail->grid.nodeCount(), std::numeric_limits<float>::quiet_NaN());
  detail->snapshot_m.assign(detail->grid.nodeCount(), std::numeric_limits<float>::quiet_NaN());
  const float mu = field_.truncation(), band = 2.0f * field_.voxelSize();
  std::vector<size_t> nodes;
  std::vector<float> alpha;
  std::vector<Eigen::Vector3f> pts;
  forEachNode(detail->grid, [&](size_t n, const Eigen::Vector3f& p) {
    const Corners c = locate(coarse, p);
    float t = 0, a = 0;
    bool observed = true;
    for (int k = 0; k < 8 && observed; ++k) {
      if (c.weight[k] <= 0.0f) continue;
      const auto node = static_cast<size_t>(c.node[k]);
      observed = snapshot_weight_[node] > 0.0f;
      t += c.weight[k] * snapshot_sdf_[node];
      a += c.weight[k] * share[node];
    }
    if (!observed || a < min_share || a <= 0.0f || std::abs(t) > band) return;
    detail->snapshot_m[n] = t;
    nodes.push_back(n);
    alpha.push_back(a);
    pts.push_back(p);
  });
  constexpr size_t kBatch = 4096;
  Eigen::Matrix3Xf points;
  Eigen::VectorXf s;
  for (size_t b = 0; b < pts.size(); b += kBatch) {
    const size_t m = std::min(kBatch, pts.size() - b);
    points.resize(3, static_cast<Eigen::Index>(m));
    for (size_t i = 0; i < m; ++i) points.col(static_cast<Eigen::Index>(i)) = pts[b + i];
    field_.forward(points, s, nullptr, nullptr);
    for (size_t i = 0; i < m; ++i) {
      const float v = s[static_cast<Eigen::Index>(i)];
      if (!std::isfinite(v)) continue;
      const size_t node = nodes[b + i];
      const float t = detail->snapshot_m[node];
      detail->refined_m[node] = t + alpha[b + i] * (std::clamp(v, -mu, mu) - t);
      ++detail->detailed_nodes;
    }
  }
  if (detail->detailed_nodes == 0) return nullptr;
  return detail;
}

}  // namespace hxmap::alg
