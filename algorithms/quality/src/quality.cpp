#include "hxmap/quality/quality.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <unordered_set>

namespace hxmap::alg {

const char* indicatorName(int indicator) {
  static const char* names[] = {"cgn", "uf", "obg", "rm", "priority"};
  return names[std::clamp(indicator, 0, static_cast<int>(kIndicatorCount))];
}

Indicators indicatorsOf(const BlockQuality& q, float truncation_m, const QualityParams& p) {
  const float inv_mu = 1.0f / truncation_m;
  auto unit = [&](float meters) { return std::min(1.0f, meters * inv_mu); };
  Indicators out{};
  out[kCgn] =
      static_cast<float>(p.alpha_coverage) * q.coverage_new + static_cast<float>(p.alpha_normal) * q.normal_novelty;
  // UF: where no neural field exists the weights renormalize to sigma_TSDF alone.
  if (q.sigma_neural_m >= 0.0f && p.w_explicit + p.w_implicit > 0.0) {
    out[kUf] = static_cast<float>((p.w_explicit * unit(q.sigma_tsdf_m) + p.w_implicit * unit(q.sigma_neural_m)) /
                                  (p.w_explicit + p.w_implicit));
  } else {
    out[kUf] = unit(q.sigma_tsdf_m);
  }
  const float view_std = q.views > 1 ? std::sqrt(std::max(0.0f, q.view_m2) / static_cast<float>(q.views - 1)) : 0.0f;
  out[kObg] = static_cast<float>(p.beta_depth_var) * unit(view_std) + static_cast<float>(p.beta_boundary) * q.boundary;
  out[kRm] = static_cast<float>(p.gamma_photometric) * q.photometric +
             static_cast<float>(p.gamma_depth) * unit(q.depth_error_m);
  return out;
}

namespace {

// One keyframe's samples in one block.
struct BlockSamples {
  BlockKey key;
  uint32_t n = 0;
  uint32_t novelty_n = 0, photo_n = 0, good_n = 0;
  float novelty_sum = 0, boundary_sum = 0, signed_sum = 0, abs_sum = 0, photo_sum = 0;
};

// The pooled standard deviation of the SDF observations (each voxel's
// Welford statistics) of the voxels within one voxel of the surface.
// (The standard error of the fused value, sigma / sqrt(n), was measured
// too: it ranks a far, much-seen clean wall with a noisy patch, 0.12 vs 0.12
// normalized on the quality room, where sigma gives 0.19 vs 0.51.)
float surfaceSigma(const VoxelBlock& block, float voxel_m) {
  double m2 = 0, dof = 0;
  for (int i = 0; i < kBlockVoxels; ++i) {
    const VoxelGeometry& g = block.geo[i];
    if (!(g.weight > 0.0f) || std::abs(g.sdf_m) >= voxel_m) continue;
    const VoxelStats& s = block.stats[i];
    if (s.updates < 2) continue;
    m2 += s.m2;
    dof += s.updates - 1;
  }
  return dof > 0 ? static_cast<float>(std::sqrt(m2 / dof)) : 0.0f;
}

float blend(float old_value, float value, float s, bool first) {
  return first ? value : old_value + s * (value - old_value);
}

}  // namespace

namespace {

// One keyframe against the model rendered at its pose, sample by sample,
// pooled per block.
class KeyframeSampler {
 public:
  KeyframeSampler(const TsdfMap& map, const KeyframeView& kf, const QualityParams& params)
      : f_(*kf.frame), m_(*kf.model), cache_(map) {
    has_normals_ = !f_.normal.empty() && !m_.normal_world.empty();
    has_model_vertex_ = !m_.vertex_world.empty() && m_.vertex_world.size() == m_.depth.size();
    has_photo_ = !f_.intensity.empty() && f_.intensity.size() == f_.depth.size() && !m_.vertex_world.empty();
    mu_ = map.truncation();
    jump_ = static_cast<float>(params.boundary_jump_ratio);
    radius_ = std::max(1, params.boundary_radius_px);
    R_ = kf.T_world_cam.linear();
    t_ = kf.T_world_cam.translation();
    inv_bs_ = 1.0f / map.blockSize();
    cos_good_ = static_cast<float>(std::cos(params.max_view_incidence_deg * M_PI / 180.0));
    voxel_m_ = map.voxelSize();
    border_px_m_ = 2.0f * static_cast<float>(f_.camera.fx) * voxel_m_;  // two voxels' footprint at 1 m, in pixels
    max_depth_ = static_cast<float>(map.params().max_integration_depth_m);
  }

  /// Pixel (u, v): counted in its block when usable (true).
  bool sample(int u, int v) {
    const float z = f_.depth.ptr<float>(v)[u];
    if (!usable(u, v, z)) return false;
    const Eigen::Vector3f p_world = R_ * f_.camera.backproject(static_cast<float>(u), static_cast<float>(v), z) + t_;
    const BlockKey key = blockOf(p_world);
    if (key != last_key_ || acc_.empty()) {
      last_slot_ = slotOf(key);
      last_key_ = key;
    }
    BlockSamples& a = acc_[last_slot_];
    ++a.n;
    a.boundary_sum += occlusionEdge(u, v, z) ? 1.0f : 0.0f;
    if (!compare(a, u, v, z)) return true;
    creditView(key, u, v);  // last: it may grow acc_, which `a` points into
    return true;
  }

  const std::vector<BlockSamples>& blocks() const { return acc_; }

 private:
  BlockKey blockOf(const Eigen::Vector3f& p_world) const {
    const Eigen::Vector3f q = p_world * inv_bs_;
    return BlockKey(floorToInt(q.x()), floorToInt(q.y()), floorToInt(q.z()));
  }

  uint32_t slotOf(const BlockKey& key) {
    auto [it, inserted] = slot_of_.try_emplace(packBlockKey(key), static_cast<uint32_t>(acc_.size()));
    if (inserted) acc_.push_back(BlockSamples{key});
    return it->second;
  }

  bool usable(int u, int v, float z) const {
    if (!(z > 0.0f) || !std::isfinite(z)) return false;
    // Beyond the fusion range the map never holds a surface: a miss there
    // says nothing about it (counted, the walls of a room larger than 4 m
    // were the Replica slice's worst blocks).
    if (z > max_depth_) return false;
    // Near the image border a rendering's miss says nothing about the map:
    // voxels at the frustum's edge are seen from inside only, and a
    // trilinear sample needs all 8 (counted, frontier wall strips ranked
    // among the worst blocks).
    if (const float zm0 = m_.depth.ptr<float>(v)[u]; !(zm0 > 0.0f && std::isfinite(zm0))) {
      const int W = f_.depth.cols, H = f_.depth.rows;
      const int margin = static_cast<int>(border_px_m_ / z) + 1;
      if (u < margin || v < margin || u >= W - margin || v >= H - margin) return false;
    }
    return true;
  }

  // Occlusion boundary: a depth jump within `radius` pixels along a row or
  // a column, on its near side (invalid neighbours are not jumps: holes are
  // not edges).
  bool occlusionEdge(int u, int v, float z) const {
    const int W = f_.depth.cols, H = f_.depth.rows;
    bool edge = false;
    for (int r = 1; r <= radius_ && !edge; ++r) {
      const int nb[4][2] = {{u - r, v}, {u + r, v}, {u, v - r}, {u, v + r}};
      for (const auto& [uu, vv] : nb) {
        if (uu < 0 || vv < 0 || uu >= W || vv >= H) continue;
        const float zn = f_.depth.ptr<float>(vv)[uu];
        if (zn - z > jump_ * z) edge = true;  // a farther neighbour: this sample occludes it
      }
    }
    return edge;
  }

  // The keyframe against the model at the pixel: depth mismatch, normal
  // novelty, color. False where the map shows no surface.
  bool compare(BlockSamples& a, int u, int v, float z) {
    const float zm = m_.depth.ptr<float>(v)[u];
    if (!(zm > 0.0f) || !std::isfinite(zm)) {
      a.signed_sum -= mu_;
      a.abs_sum += mu_;
      return false;
    }
    const float e = std::clamp(z - zm, -mu_, mu_);
    a.signed_sum += e;
    a.abs_sum += std::abs(e);
    if (has_normals_) {
      const cv::Vec3f nf = f_.normal.ptr<cv::Vec3f>(v)[u];
      const cv::Vec3f nm = m_.normal_world.ptr<cv::Vec3f>(v)[u];
      if (nf[2] != 0.0f && (nm[0] != 0.0f || nm[1] != 0.0f || nm[2] != 0.0f)) {
        const Eigen::Vector3f nfw = R_ * Eigen::Vector3f(nf[0], nf[1], nf[2]);
        a.novelty_sum += 1.0f - std::min(1.0f, std::abs(nfw.dot(Eigen::Vector3f(nm[0], nm[1], nm[2]))));
        ++a.novelty_n;
      }
    }
    if (has_photo_) {
      const cv::Vec3f vm = m_.vertex_world.ptr<cv::Vec3f>(v)[u];
      Eigen::Vector3f rgb;
      if (cache_.sampleColor(Eigen::Vector3f(vm[0], vm[1], vm[2]), rgb)) {
        // Gray as the frame's intensity (ITU-R 601 weights, [0, 1]).
        const float gray = (0.299f * rgb.x() + 0.587f * rgb.y() + 0.114f * rgb.z()) * (1.0f / 255.0f);
        a.photo_sum += std::abs(f_.intensity.ptr<float>(v)[u] - gray);
        ++a.photo_n;
      }
    }
    return true;
  }

  // A usable view of the map's surface (the model's normal against the
  // pixel's ray), credited to the blocks within half a voxel of the model's
  // surface point along its normal: a surface on a block's face is the zero
  // crossing between the voxels on both sides. (The keyframe's own point
  // and normal scatter with the sensor noise and credited blocks next to a
  // surface that hold none of it.)
  void creditView(const BlockKey& key, int u, int v) {
    if (!has_normals_ || !has_model_vertex_) return;
    const cv::Vec3f nm = m_.normal_world.ptr<cv::Vec3f>(v)[u];
    if (nm[0] == 0.0f && nm[1] == 0.0f && nm[2] == 0.0f) return;
    const Eigen::Vector3f ray = R_ * f_.camera.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
    if (!(std::abs(nm[0] * ray.x() + nm[1] * ray.y() + nm[2] * ray.z()) >= cos_good_ * ray.norm())) return;
    const cv::Vec3f vm = m_.vertex_world.ptr<cv::Vec3f>(v)[u];
    const Eigen::Vector3f pm(vm[0], vm[1], vm[2]), half = (0.5f * voxel_m_) * Eigen::Vector3f(nm[0], nm[1], nm[2]);
    const BlockKey ka = blockOf(pm - half), kb = blockOf(pm + half);
    // Mostly the sample's own block (`key`), whose slot is known.
    ++acc_[ka == key ? last_slot_ : slotOf(ka)].good_n;
    if (kb != ka) ++acc_[kb == key ? last_slot_ : slotOf(kb)].good_n;
  }

  const FrameLevel& f_;
  const ModelView& m_;
  BlockCache cache_;
  bool has_normals_ = false, has_model_vertex_ = false, has_photo_ = false;
  float mu_ = 0, jump_ = 0, inv_bs_ = 0, cos_good_ = 0, voxel_m_ = 0, border_px_m_ = 0, max_depth_ = 0;
  int radius_ = 1;
  Eigen::Matrix3f R_;
  Eigen::Vector3f t_;
  std::vector<BlockSamples> acc_;
  std::unordered_map<uint64_t, uint32_t> slot_of_;
  BlockKey last_key_{std::numeric_limits<int>::min(), 0, 0};
  uint32_t last_slot_ = 0;
};

}  // namespace

QualityUpdateStats QualityMap::update(const TsdfMap& map, const KeyframeView& kf) {
  QualityUpdateStats stats;
  if (!kf.frame || !kf.model || kf.frame->depth.empty() || kf.frame->depth.size() != kf.model->depth.size()) {
    return stats;
  }
  KeyframeSampler sampler(map, kf, params_);
  const int stride = std::max(1, params_.pixel_stride);
  for (int v = stride / 2; v < kf.frame->depth.rows; v += stride) {
    for (int u = stride / 2; u < kf.frame->depth.cols; u += stride) stats.samples += sampler.sample(u, v) ? 1 : 0;
  }
  const float voxel_m = map.voxelSize();
  const Eigen::Vector3f t = kf.T_world_cam.translation();
  const std::vector<BlockSamples>& acc = sampler.blocks();
  const float s = static_cast<float>(std::clamp(params_.smoothing, 0.0, 1.0));
  const uint32_t min_samples = static_cast<uint32_t>(std::max(1, params_.min_samples));
  const float views_needed = static_cast<float>(std::max(1, params_.consolidated_views));
  for (const BlockSamples& a : acc) {
    if (a.n < min_samples) continue;
    BlockQuality& q = blocks_[pack(a.key)];
    const bool first = q.views == 0;
    const float inv_n = 1.0f / static_cast<float>(a.n);

    q.good_views += a.good_n >= min_samples;
    q.coverage_new = std::max(0.0f, 1.0f - static_cast<float>(q.good_views) / views_needed);
    const int32_t b = map.find(a.key);
    q.sigma_tsdf_m = b >= 0 ? surfaceSigma(map.block(b), voxel_m) : 0.0f;

    if (a.novelty_n > 0) {
      q.normal_novelty = blend(q.normal_novelty, a.novelty_sum / static_cast<float>(a.novelty_n), s, first);
    }
    const float full = static_cast<float>(std::max(1e-3, params_.boundary_full_share));
    q.boundary = blend(q.boundary, std::min(1.0f, a.boundary_sum * inv_n / full), s, first);
    if (a.photo_n > 0) q.photometric = blend(q.photometric, a.photo_sum / static_cast<float>(a.photo_n), s, first);
    q.depth_error_m = blend(q.depth_error_m, a.abs_sum * inv_n, s, first);

    // Welford over keyframes of this view's mean signed mismatch.
    const float view_mean = a.signed_sum * inv_n;
    ++q.views;
    const float delta = view_mean - q.view_mean_m;
    q.view_mean_m += delta / static_cast<float>(q.views);
    q.view_m2 += delta * (view_mean - q.view_mean_m);

    keepKeyframe(q, (a.key.cast<float>() + Eigen::Vector3f::Constant(0.5f)) * map.blockSize(), kf.id, a.n, t);
    ++stats.blocks_scored;
  }
  if (auto it = keyframes_.find(kf.id); it != keyframes_.end() && it->second.blocks == 0) keyframes_.erase(it);
  return stats;
}

void QualityMap::keepKeyframe(BlockQuality& q, const Eigen::Vector3f& block_center_world, uint32_t id, uint32_t samples,
                              const Eigen::Vector3f& camera_world) {
  // DESIGN: refinement trains an ROI's field on the keyframes its blocks
  // keep. Kept by recency, they were the last few views along the path,
  // a few degrees apart: the TSDF's errors that only other directions
  // reveal (the negative shadow it grows behind a thin rod, seen through
  // from the side) were never in a job's rays. Kept by spread, a block
  // holds the views farthest apart in direction; among near-identical
  // views the newest, whose pose the tracker and the feedback have settled.
  KeptKeyframe& kept = keyframes_[id];
  kept.center_world = camera_world;
  const Eigen::Vector3f dir = (camera_world - block_center_world).normalized();
  const auto n = static_cast<int>(q.keyframe_count);
  int slot = n;
  if (n == BlockQuality::kMaxKeyframes) {
    if (!params_.spread_keyframes) {
      slot = 0;  // the oldest: ids grow with time
      for (int k = 1; k < n; ++k) slot = q.keyframe_ids[k] < q.keyframe_ids[slot] ? k : slot;
    } else {
      // The closest pair among the kept and the new; out goes its older.
      float best = -2.0f;
      for (int i = 0; i < n; ++i) {
        const float c_new = q.keyframe_dirs[i].dot(dir);
        if (c_new > best) {
          best = c_new;
          slot = i;
        }
        for (int j = i + 1; j < n; ++j) {
          const float c = q.keyframe_dirs[i].dot(q.keyframe_dirs[j]);
          if (c > best) {
            best = c;
            slot = q.keyframe_ids[i] < q.keyframe_ids[j] ? i : j;
          }
        }
      }
    }
    auto it = keyframes_.find(q.keyframe_ids[slot]);
    if (it != keyframes_.end() && --it->second.blocks == 0) keyframes_.erase(it);
  } else {
    ++q.keyframe_count;
  }
  q.keyframe_ids[slot] = id;
  q.keyframe_samples[slot] = static_cast<uint16_t>(std::min<uint32_t>(samples, 65535));
  q.keyframe_dirs[slot] = dir;
  ++kept.blocks;
}

uint32_t QualityMap::keyframeReferences(uint32_t id) const {
  auto it = keyframes_.find(id);
  return it == keyframes_.end() ? 0 : it->second.blocks;
}

void QualityMap::setNeuralSigma(const BlockKey& key, float sigma_m) {
  auto it = blocks_.find(pack(key));
  if (it != blocks_.end() && std::isfinite(sigma_m)) it->second.sigma_neural_m = std::max(0.0f, sigma_m);
}

const BlockQuality* QualityMap::find(const BlockKey& key) const {
  auto it = blocks_.find(pack(key));
  return it == blocks_.end() ? nullptr : &it->second;
}

std::vector<BlockScore> QualityMap::score(float truncation_m) const {
  std::vector<BlockScore> out;
  out.reserve(blocks_.size());
  Indicators lo, hi;
  lo.fill(std::numeric_limits<float>::max());
  hi.fill(std::numeric_limits<float>::lowest());
  for (const auto& [packed, q] : blocks_) {
    if (q.views == 0) continue;
    BlockScore s;
    s.key = unpack(packed);
    s.raw = indicatorsOf(q, truncation_m, params_);
    for (int k = 0; k < kIndicatorCount; ++k) {
      lo[k] = std::min(lo[k], s.raw[k]);
      hi[k] = std::max(hi[k], s.raw[k]);
    }
    out.push_back(s);
  }
  const std::array<double, kIndicatorCount> lambda{params_.lambda_cgn, params_.lambda_uf, params_.lambda_obg,
                                                   params_.lambda_rm};
  // The rule (params.hpp): the largest weighted indicator, scaled so the
  // largest weight counts fully, or eq 7's weighted sum.
  const bool sum_rule = params_.priority_rule == "sum";
  const double lambda_max = *std::max_element(lambda.begin(), lambda.end());
  const double max_scale = lambda_max > 0.0 ? 1.0 / lambda_max : 0.0;
  for (BlockScore& s : out) {
    double prio = 0;
    for (int k = 0; k < kIndicatorCount; ++k) {
      // eq 6; an indicator that is the same everywhere carries no ranking
      // information and normalizes to 0.
      const float range = hi[k] - lo[k];
      s.normalized[k] = range > 1e-9f ? (s.raw[k] - lo[k]) / range : 0.0f;
      prio = sum_rule ? prio + lambda[k] * s.normalized[k] : std::max(prio, max_scale * lambda[k] * s.normalized[k]);
    }
    s.priority = static_cast<float>(prio);
  }
  std::sort(out.begin(), out.end(), [](const BlockScore& a, const BlockScore& b) {
    if (a.priority != b.priority) return a.priority > b.priority;
    return std::lexicographical_compare(a.key.data(), a.key.data() + 3, b.key.data(), b.key.data() + 3);
  });
  return out;
}

std::vector<Roi> QualityMap::selectRois(const std::vector<BlockScore>& scores, float voxel_size_m) const {
  size_t budget =
      static_cast<size_t>(std::ceil(std::clamp(params_.top_fraction, 0.0, 1.0) * static_cast<double>(scores.size())));
  if (params_.max_blocks > 0) budget = std::min(budget, static_cast<size_t>(params_.max_blocks));
  std::unordered_map<uint64_t, size_t> chosen;  // packed key -> index in scores
  for (size_t i = 0; i < scores.size() && chosen.size() < budget; ++i) {
    if (scores[i].priority < params_.min_priority) break;
    chosen.emplace(pack(scores[i].key), i);
  }

  // Connected components (26-neighbourhood), visited in priority order so
  // the result does not depend on hash order.
  std::vector<std::vector<size_t>> components;
  std::unordered_set<uint64_t> seen;
  for (size_t i = 0; i < scores.size(); ++i) {
    const uint64_t p = pack(scores[i].key);
    if (!chosen.count(p) || seen.count(p)) continue;
    std::vector<size_t> comp{i};
    seen.insert(p);
    for (size_t head = 0; head < comp.size(); ++head) {
      const BlockKey k = scores[comp[head]].key;
      for (int dz = -1; dz <= 1; ++dz) {
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const uint64_t n = pack(k + BlockKey(dx, dy, dz));
            auto it = chosen.find(n);
            if (it == chosen.end() || !seen.insert(n).second) continue;
            comp.push_back(it->second);
          }
        }
      }
    }
    components.push_back(std::move(comp));
  }

  // Each component cut into cubes of at most `extent` blocks per side,
  // anchored at the component's lowest corner.
  const int extent = std::max(1, params_.roi_max_extent_blocks);
  const float bs = voxel_size_m * kBlockSide;
  const float margin = static_cast<float>(params_.roi_margin_voxels) * voxel_size_m;
  std::vector<Roi> rois;
  for (const auto& comp : components) {
    BlockKey lo = scores[comp[0]].key;
    for (size_t i : comp) lo = lo.cwiseMin(scores[i].key);
    std::map<std::array<int, 3>, size_t> tile_roi;
    for (size_t i : comp) {
      const BlockKey c = (scores[i].key - lo) / extent;  // non-negative: plain division floors
      auto [it, inserted] = tile_roi.try_emplace({c.x(), c.y(), c.z()}, rois.size());
      if (inserted) rois.emplace_back();
      Roi& roi = rois[it->second];
      roi.blocks.push_back(scores[i].key);
      roi.priority = std::max(roi.priority, scores[i].priority);
    }
  }
  for (Roi& roi : rois) {
    BlockKey lo = roi.blocks[0], hi = roi.blocks[0];
    std::unordered_map<uint32_t, uint32_t> kf_samples;
    for (const BlockKey& k : roi.blocks) {
      lo = lo.cwiseMin(k);
      hi = hi.cwiseMax(k);
      if (const BlockQuality* q = find(k)) {
        for (uint32_t j = 0; j < q->keyframe_count; ++j) kf_samples[q->keyframe_ids[j]] += q->keyframe_samples[j];
      }
    }
    roi.box_world = Eigen::AlignedBox3f(lo.cast<float>() * bs - Eigen::Vector3f::Constant(margin),
                                        (hi + BlockKey::Ones()).cast<float>() * bs + Eigen::Vector3f::Constant(margin));
    std::vector<std::pair<uint32_t, uint32_t>> kfs(kf_samples.begin(), kf_samples.end());
    std::sort(kfs.begin(), kfs.end(), [](const auto& a, const auto& b) {
      return a.second != b.second ? a.second > b.second : a.first > b.first;
    });
    const auto cap = static_cast<size_t>(std::max(0, params_.roi_max_keyframes));
    if (!params_.spread_keyframes || kfs.size() <= cap) {
      if (kfs.size() > cap) kfs.resize(cap);
      for (const auto& [id, n] : kfs) roi.keyframes.push_back(id);
      continue;
    }
    // Spread: the keyframe that saw the region most, then each time the one
    // farthest in direction from all chosen (the smallest largest cosine),
    // among those with at least a quarter of the best's samples; the rest,
    // if any room is left, by samples.
    const Eigen::Vector3f c = roi.box_world.center();
    std::vector<Eigen::Vector3f> dirs;
    for (const auto& [id, n] : kfs) {
      auto it = keyframes_.find(id);
      dirs.push_back(it == keyframes_.end() ? Eigen::Vector3f::Zero()
                                            : Eigen::Vector3f((it->second.center_world - c).normalized()));
    }
    std::vector<char> chosen(kfs.size(), 0);
    std::vector<size_t> order{0};
    chosen[0] = 1;
    const uint32_t min_samples = kfs[0].second / 4;
    while (order.size() < cap) {
      size_t pick = kfs.size();
      float pick_cos = 2.0f;
      for (size_t i = 0; i < kfs.size(); ++i) {
        if (chosen[i] || kfs[i].second < min_samples) continue;
        float closest = -1.0f;
        for (size_t j : order) closest = std::max(closest, dirs[i].dot(dirs[j]));
        if (closest < pick_cos) {
          pick_cos = closest;
          pick = i;
        }
      }
      if (pick == kfs.size()) {
        for (pick = 0; pick < kfs.size() && chosen[pick]; ++pick) {
        }
      }
      chosen[pick] = 1;
      order.push_back(pick);
    }
    for (size_t i : order) roi.keyframes.push_back(kfs[i].first);
  }
  std::stable_sort(rois.begin(), rois.end(), [](const Roi& a, const Roi& b) { return a.priority > b.priority; });
  return rois;
}

}  // namespace hxmap::alg
