#include "hxmap/feedback/field_surface.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace hxmap::alg {

FieldSurface::FieldSurface(const NeuralField& field, float band_voxels, const std::vector<uint8_t>* seen)
    : grid_(field.fineGrid()), box_(field.box()), voxel_m_(field.voxelSize()), mu_(field.truncation()) {
  grid_.channels = 1;
  const size_t n = grid_.nodeCount();
  sdf_.assign(n, std::numeric_limits<float>::quiet_NaN());
  rgb_.assign(3 * n, 0.0f);
  // The band from the coarse grid's signed distance (channel 0, sdf / mu):
  // the field's own correction is a fraction of a voxel.
  const GridLayout& coarse = field.coarseGrid();
  const float* cp = field.parameters().data();
  const float band = band_voxels * voxel_m_;
  std::vector<size_t> nodes;
  std::vector<Eigen::Vector3f> pts;
  for (int z = 0; z < grid_.nodes.z(); ++z) {
    for (int y = 0; y < grid_.nodes.y(); ++y) {
      for (int x = 0; x < grid_.nodes.x(); ++x) {
        const Eigen::Vector3f p = grid_.origin + grid_.cell * Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y),
                                                                              static_cast<float>(z));
        const Corners c = locate(coarse, p);
        float s = 0;
        bool constrained = true;
        for (int k = 0; k < 8; ++k) {
          s += c.weight[k] * cp[static_cast<size_t>(c.node[k]) * NeuralField::kCoarseStride];
          if (seen && c.weight[k] > 0.0f && !(*seen)[static_cast<size_t>(c.node[k])]) constrained = false;
        }
        if (!constrained || std::abs(s * mu_) > band) continue;
        nodes.push_back((static_cast<size_t>(z) * grid_.nodes.y() + y) * grid_.nodes.x() + x);
        pts.push_back(p);
      }
    }
  }
  // Batched forward passes (bounded memory).
  constexpr size_t kBatch = 4096;
  Eigen::Matrix3Xf points;
  Eigen::VectorXf s;
  Eigen::Matrix3Xf c;
  for (size_t b = 0; b < pts.size(); b += kBatch) {
    const size_t m = std::min(kBatch, pts.size() - b);
    points.resize(3, static_cast<Eigen::Index>(m));
    for (size_t i = 0; i < m; ++i) points.col(static_cast<Eigen::Index>(i)) = pts[b + i];
    field.forward(points, s, &c, nullptr);
    for (size_t i = 0; i < m; ++i) {
      const size_t node = nodes[b + i];
      const float v = s[static_cast<Eigen::Index>(i)];
      if (!std::isfinite(v)) continue;
      sdf_[node] = v;
      for (int ch = 0; ch < 3; ++ch) rgb_[3 * node + ch] = 255.0f * std::clamp(c(ch, static_cast<Eigen::Index>(i)), 0.0f, 1.0f);
      ++sampled_;
    }
  }
}

bool FieldSurface::sample(const Eigen::Vector3f& p, float& sdf_m, Eigen::Vector3f* gradient, Eigen::Vector3f* rgb) const {
  if (!box_.contains(p) || sampled_ == 0) return false;
  int base[3];
  float f[3];
  for (int a = 0; a < 3; ++a) {
    const int n = grid_.nodes[a];
    const float q = std::clamp((p[a] - grid_.origin[a]) / grid_.cell, 0.0f, static_cast<float>(n - 1));
    base[a] = std::clamp(static_cast<int>(q), 0, std::max(n - 2, 0));
    f[a] = n > 1 ? q - static_cast<float>(base[a]) : 0.0f;
  }
  const int sx = grid_.nodes.x() > 1 ? 1 : 0, sy = grid_.nodes.y() > 1 ? grid_.nodes.x() : 0;
  const int sz = grid_.nodes.z() > 1 ? grid_.nodes.x() * grid_.nodes.y() : 0;
  const size_t n0 = (static_cast<size_t>(base[2]) * grid_.nodes.y() + base[1]) * grid_.nodes.x() + base[0];
  float v[8];
  size_t idx[8];
  for (int k = 0; k < 8; ++k) {
    idx[k] = n0 + static_cast<size_t>((k & 1) * sx + ((k >> 1) & 1) * sy + ((k >> 2) & 1) * sz);
    v[k] = sdf_[idx[k]];
    if (std::isnan(v[k])) return false;
  }
  const float gx = 1 - f[0], gy = 1 - f[1], gz = 1 - f[2];
  // Corner k = (dx, dy, dz) bits.
  const float c00 = v[0] * gx + v[1] * f[0], c10 = v[2] * gx + v[3] * f[0];
  const float c01 = v[4] * gx + v[5] * f[0], c11 = v[6] * gx + v[7] * f[0];
  const float c0 = c00 * gy + c10 * f[1], c1 = c01 * gy + c11 * f[1];
  sdf_m = c0 * gz + c1 * f[2];
  if (gradient) {
    const float inv = 1.0f / grid_.cell;
    const float dx0 = (v[1] - v[0]) * gy + (v[3] - v[2]) * f[1], dx1 = (v[5] - v[4]) * gy + (v[7] - v[6]) * f[1];
    const float dy0 = (v[2] - v[0]) * gx + (v[3] - v[1]) * f[0], dy1 = (v[6] - v[4]) * gx + (v[7] - v[5]) * f[0];
    (*gradient) = Eigen::Vector3f(dx0 * gz + dx1 * f[2], dy0 * gz + dy1 * f[2], c1 - c0) * inv;
  }
  if (rgb) {
    rgb->setZero();
    for (int k = 0; k < 8; ++k) {
      const float w = ((k & 1) ? f[0] : gx) * (((k >> 1) & 1) ? f[1] : gy) * (((k >> 2) & 1) ? f[2] : gz);
      *rgb += w * Eigen::Vector3f(rgb_[3 * idx[k]], rgb_[3 * idx[k] + 1], rgb_[3 * idx[k] + 2]);
    }
  }
  return true;
}

bool FieldSurface::intersect(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float t_hint, float& t,
                             Eigen::Vector3f& normal, Eigen::Vector3f& rgb) const {
  // A bracket of 1.5 voxels on either side of the hint, else the first
  // front-to-back crossing within the truncation band around it.
  float ta = t_hint - 1.5f * voxel_m_, tb = t_hint + 1.5f * voxel_m_, sa = 0, sb = 0;
  bool bracketed = sample(o + ta * d, sa, nullptr, nullptr) && sa > 0 && sample(o + tb * d, sb, nullptr, nullptr) && sb <= 0;
  if (!bracketed) {
    const float step = grid_.cell;
    float prev_t = -1, prev_s = 0;
    for (float tt = std::max(0.0f, t_hint - mu_); tt <= t_hint + mu_; tt += step) {
      float s = 0;
      if (!sample(o + tt * d, s, nullptr, nullptr)) {
        prev_t = -1;
        continue;
      }
      if (prev_t >= 0 && prev_s > 0 && s <= 0) {
        ta = prev_t, sa = prev_s, tb = tt, sb = s;
        bracketed = true;
        break;
      }
      prev_t = tt, prev_s = s;
    }
  }
  if (!bracketed) return false;
  t = ta + (tb - ta) * sa / (sa - sb);
  for (int k = 0; k < 2; ++k) {  // secants on the side that still brackets
    float s = 0;
    if (!sample(o + t * d, s, nullptr, nullptr)) return false;
    if (std::abs(s) < 1e-6f) break;
    if (s > 0) {
      ta = t, sa = s;
    } else {
      tb = t, sb = s;
    }
    t = ta + (tb - ta) * sa / (sa - sb);
  }
  float s = 0;
  return sample(o + t * d, s, &normal, &rgb) && normal.squaredNorm() > 1e-12f;
}

}  // namespace hxmap::alg
