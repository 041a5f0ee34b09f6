#include "hxmap/implicit/neural_field.hpp"

#include <algorithm>
#include <cmath>

#include "hxmap/core/simd.hpp"
#include "hxmap/implicit/activation.hpp"

namespace hxmap::alg {

namespace {

// splitmix64: a deterministic stream for the initial weights.
struct SplitMix {
  uint64_t state;
  uint64_t next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  float uniform(float lo, float hi) { return lo + (hi - lo) * static_cast<float>(next() >> 40) * 0x1.0p-24f; }
};

/// Y = softplus(A) and S = softplus'(A), pads included (they stay finite).
void activate(const PointRows& A, float* Y, PointRows& S) {
  S.resize(A.rows(), A.points());
  softplusAndSlope(A.data(), Y, S.data(), A.size());
}

// sin(pi q) and cos(pi q): q = n + r with n an integer and |r| <= 1/2,
// then Taylor polynomials of pi r to the 11th and 12th power (within
// 6e-8 absolute on [-pi/2, pi/2]); both change sign with n's parity.
// Branch-free, so that a loop of them vectorizes.
HXMAP_INLINE_IN_CLONES void sinCosPi(float q, float& sn, float& cs) {
  const auto n = static_cast<int32_t>(q + (q >= 0.0f ? 0.5f : -0.5f));
  const float x = static_cast<float>(M_PI) * (q - static_cast<float>(n));
  const float x2 = x * x;
  const float s =
      x * (1.0f +
           x2 * (-1.0f / 6 + x2 * (1.0f / 120 + x2 * (-1.0f / 5040 + x2 * (1.0f / 362880 + x2 * (-1.0f / 39916800))))));
  const float c =
      1.0f +
      x2 * (-0.5f + x2 * (1.0f / 24 +
                          x2 * (-1.0f / 720 + x2 * (1.0f / 40320 + x2 * (-1.0f / 3628800 + x2 * (1.0f / 479001600))))));
  const float sign = (n & 1) ? -1.0f : 1.0f;
  sn = sign * s;
  cs = sign * c;
}

/// G *= S, element by element (a gradient through an activation's slope).
void scaleBySlope(PointRows& G, const PointRows& S) {
  float* g = G.data();
  const float* s = S.data();
  for (size_t i = 0; i < G.size(); ++i) g[i] *= s[i];
}

// locate() with the cell's inverse given (one multiply per axis instead of
// a division), inlined into the field's loops.
inline Corners locateScaled(const GridLayout& grid, float inv_cell, const Eigen::Vector3f& p) {
  Corners c;
  int base[3];
  float frac[3];
  for (int a = 0; a < 3; ++a) {
    const int n = grid.nodes[a];
    float q = (p[a] - grid.origin[a]) * inv_cell;
    q = std::clamp(q, 0.0f, static_cast<float>(n - 1));
    int i = std::min(static_cast<int>(q), std::max(n - 2, 0));
    base[a] = i;
    frac[a] = n > 1 ? q - static_cast<float>(i) : 0.0f;
  }
  const int sx = grid.nodes.x() > 1 ? 1 : 0, sy = grid.nodes.y() > 1 ? grid.nodes.x() : 0;
  const int sz = grid.nodes.z() > 1 ? grid.nodes.x() * grid.nodes.y() : 0;
  const int n0 = (base[2] * grid.nodes.y() + base[1]) * grid.nodes.x() + base[0];
  for (int k = 0; k < 8; ++k) {
    const int dx = k & 1, dy = (k >> 1) & 1, dz = (k >> 2) & 1;
    c.node[k] = n0 + dx * sx + dy * sy + dz * sz;
    c.weight[k] = (dx ? frac[0] : 1 - frac[0]) * (dy ? frac[1] : 1 - frac[1]) * (dz ? frac[2] : 1 - frac[2]);
  }
  return c;
}

}  // namespace

Corners locate(const GridLayout& grid, const Eigen::Vector3f& p) { return locateScaled(grid, 1.0f / grid.cell, p); }

void TouchedNodes::begin(size_t node_count) {
  nodes_.clear();
  if (stamp_.size() != node_count || ++current_ == 0) {
    stamp_.assign(node_count, 0);
    current_ = 1;
  }
}

NeuralField::NeuralField(const TsdfMap& map, const Eigen::Vector3i& voxel_min, const Eigen::Vector3i& voxel_count,
                         const ImplicitParams& params)
    : voxel_min_(voxel_min),
      voxel_count_(voxel_count.cwiseMax(2)),
      voxel_size_(map.voxelSize()),
      mu_(map.truncation()),
      fuse_(std::max(1, params.fuse_width)),
      hidden_(std::max(1, params.hidden_width)),
      frequencies_(std::max(0, params.encoding_frequencies)) {
  const Eigen::Vector3f lo = map.voxelCenter(voxel_min_);
  const Eigen::Vector3f hi = map.voxelCenter(voxel_min_ + voxel_count_ - Eigen::Vector3i::Ones());
  box_ = Eigen::AlignedBox3f(lo, hi);
  center_ = box_.center();
  inv_half_extent_ = (0.5f * (hi - lo)).cwiseMax(1e-6f).cwiseInverse();

  coarse_ = GridLayout{lo, voxel_size_, voxel_count_, kCoarseStride};
  const int f = std::max(1, params.fine_per_voxel);
  fine_ = GridLayout{lo, voxel_size_ / static_cast<float>(f), (voxel_count_ - Eigen::Vector3i::Ones()) * f +
                                                                  Eigen::Vector3i::Ones(), 1};
  const int in0 = inputWidth(), in1 = fuse_ + encodingWidth();
  size_t off = gridParameters();
  wf_ = off, off += static_cast<size_t>(fuse_) * in0;
  bf_ = off, off += static_cast<size_t>(fuse_);
  w1_ = off, off += static_cast<size_t>(hidden_) * in1;
  b1_ = off, off += static_cast<size_t>(hidden_);
  w2_ = off, off += static_cast<size_t>(4) * hidden_;
  b2_ = off, off += 4;
  params_.assign(off, 0.0f);

  // Coarse grid from the map: sdf / mu (unobserved: free space), color.
  const int nx = voxel_count_.x(), ny = voxel_count_.y(), nz = voxel_count_.z();
  std::vector<uint8_t> observed(coarse_.nodeCount(), 0);
  for (int z = 0; z < nz; ++z) {
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        const size_t n = (static_cast<size_t>(z) * ny + y) * nx + x;
        float* v = &params_[n * kCoarseStride];
        Voxel vox;
        if (map.voxel(voxel_min_ + Eigen::Vector3i(x, y, z), vox) && vox.weight > 0.0f) {
          observed[n] = 1;
          v[0] = std::clamp(vox.sdf_m / mu_, -1.0f, 1.0f);
          v[4] = vox.color.r / 255.0f, v[5] = vox.color.g / 255.0f, v[6] = vox.color.b / 255.0f;
        } else {
          v[0] = 1.0f;
          v[4] = v[5] = v[6] = 0.5f;
        }
      }
    }
  }
  // Normals: central differences of the signed distance where both
  // neighbours are observed (one-sided at the edge of what is known).
  auto at = [&](int x, int y, int z) { return (static_cast<size_t>(z) * ny + y) * nx + x; };
  for (int z = 0; z < nz; ++z) {
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        const size_t n = at(x, y, z);
        if (!observed[n]) continue;
        const int p[3] = {x, y, z}, lim[3] = {nx, ny, nz};
        Eigen::Vector3f g = Eigen::Vector3f::Zero();
        for (int a = 0; a < 3; ++a) {
          int q0[3] = {p[0], p[1], p[2]}, q1[3] = {p[0], p[1], p[2]};
          q0[a] = std::max(0, p[a] - 1), q1[a] = std::min(lim[a] - 1, p[a] + 1);
          size_t n0 = at(q0[0], q0[1], q0[2]), n1 = at(q1[0], q1[1], q1[2]);
          if (!observed[n0]) n0 = n;
          if (!observed[n1]) n1 = n;
          const int span = (n1 != n ? 1 : 0) + (n0 != n ? 1 : 0);
          if (span > 0) g[a] = (params_[n1 * kCoarseStride] - params_[n0 * kCoarseStride]) / static_cast<float>(span);
        }
        const float len = g.norm();
        if (len > 1e-6f) {
          for (int a = 0; a < 3; ++a) params_[n * kCoarseStride + 1 + a] = g[a] / len;
        }
      }
    }
  }
  initDecoder(params.seed);
}

void NeuralField::initDecoder(uint64_t seed) {
  SplitMix rng{seed * 0x2545F4914F6CDD1DULL + 1};
  auto xavier = [&](size_t off, int out, int in) {
    const float a = std::sqrt(6.0f / static_cast<float>(in + out));
    for (size_t i = 0; i < static_cast<size_t>(out) * in; ++i) params_[off + i] = rng.uniform(-a, a);
  };
  xavier(wf_, fuse_, inputWidth());
  xavier(w1_, hidden_, fuse_ + encodingWidth());
  // W_2 and b_2 stay zero: the untrained field is the TSDF.
}

void NeuralField::encode(const Eigen::Matrix3Xf& points, PointRows& rows, int first) const {
  // Per point: q (the local position in [-1, 1]), then per octave
  // sin(pi 2^f q) and cos(pi 2^f q) of each axis; the first octave from
  // sin/cos, each next one by the double-angle rule. Pads get q = 0.
  const size_t n = static_cast<size_t>(points.cols()), stride = rows.stride();
  const float* p = points.data();
  for (int a = 0; a < 3; ++a) {
    float* q = rows.row(first + a);
    const float c = center_[a], k = inv_half_extent_[a];
    for (size_t j = 0; j < n; ++j) q[j] = (p[3 * j + static_cast<size_t>(a)] - c) * k;
    for (size_t j = n; j < stride; ++j) q[j] = 0.0f;
  }
  const int freqs = frequencies_;
  dispatchAvx2Fma([&]() HXMAP_LAMBDA_INLINE_IN_CLONES {
    for (int a = 0; a < 3; ++a) {
      const float* q = rows.row(first + a);
      if (freqs == 0) continue;
      float* sn = rows.row(first + 3 + 2 * a);
      float* cs = rows.row(first + 3 + 2 * a + 1);
      for (size_t j = 0; j < stride; ++j) sinCosPi(q[j], sn[j], cs[j]);
      for (int f = 1; f < freqs; ++f) {
        const float* s0 = rows.row(first + 3 + 6 * (f - 1) + 2 * a);
        const float* c0 = rows.row(first + 3 + 6 * (f - 1) + 2 * a + 1);
        float* s1 = rows.row(first + 3 + 6 * f + 2 * a);
        float* c1 = rows.row(first + 3 + 6 * f + 2 * a + 1);
        for (size_t j = 0; j < stride; ++j) {
          s1[j] = 2.0f * s0[j] * c0[j];
          c1[j] = (c0[j] - s0[j]) * (c0[j] + s0[j]);
        }
      }
    }
  });
}

void NeuralField::forward(const Eigen::Matrix3Xf& points, Eigen::VectorXf& sdf_m, Eigen::Matrix3Xf* rgb,
                          Cache* cache) const {
  const auto n = static_cast<size_t>(points.cols());
  Cache local;
  Cache& c = cache ? *cache : local;
  const int in0 = inputWidth(), enc = encodingWidth();
  c.X.resize(in0, n);
  c.Zin.resize(fuse_ + enc, n);
  const bool keep = cache != nullptr;
  if (keep) {
    c.coarse.resize(n);
    c.fine.resize(n);
  }
  const size_t stride = c.X.stride();
  const float* fine = params_.data() + fineOffset();
  float* X[kCoarseChannels + 1];
  for (int ch = 0; ch <= kCoarseChannels; ++ch) X[ch] = c.X.row(ch);
  const float inv_coarse = 1.0f / coarse_.cell, inv_fine = 1.0f / fine_.cell;
  const float* coarse = params_.data();
  dispatchAvx2Fma([&]() HXMAP_LAMBDA_INLINE_IN_CLONES {
    for (size_t j = 0; j < n; ++j) {
      const Eigen::Vector3f p = points.col(static_cast<Eigen::Index>(j));
      const Corners cc = locateScaled(coarse_, inv_coarse, p), fc = locateScaled(fine_, inv_fine, p);
      Lanes v{};  // a coarse node's channels are one vector
      for (int k = 0; k < 8; ++k) {
        Lanes node;
        loadLanes(node, coarse + static_cast<size_t>(cc.node[k]) * kCoarseStride);
        v += cc.weight[k] * node;
      }
      float s_fine = 0;
      for (int k = 0; k < 8; ++k) s_fine += fc.weight[k] * fine[fc.node[k]];
      for (int ch = 0; ch < kCoarseChannels; ++ch) X[ch][j] = v[ch];
      X[kCoarseChannels][j] = s_fine;
      if (keep) c.coarse[j] = cc, c.fine[j] = fc;
    }
  });
  for (int ch = 0; ch <= kCoarseChannels; ++ch) std::fill(X[ch] + n, X[ch] + stride, 0.0f);
  encode(points, c.Zin, fuse_);
  denseForward(params_.data() + wf_, params_.data() + bf_, fuse_, in0, c.X, c.A);
  activate(c.A, c.Zin.row(0), c.S0);  // z: the first fuse_ rows of the decoder's input
  denseForward(params_.data() + w1_, params_.data() + b1_, hidden_, fuse_ + enc, c.Zin, c.A);
  c.H.resize(hidden_, n);
  activate(c.A, c.H.data(), c.S1);
  denseForward(params_.data() + w2_, params_.data() + b2_, 4, hidden_, c.H, c.O);
  sdf_m.resize(static_cast<Eigen::Index>(n));
  const float* o0 = c.O.row(0);
  for (size_t j = 0; j < n; ++j) sdf_m[static_cast<Eigen::Index>(j)] = mu_ * (X[0][j] + X[kCoarseChannels][j] + o0[j]);
  if (rgb) {
    rgb->resize(3, static_cast<Eigen::Index>(n));
    for (int a = 0; a < 3; ++a) {
      const float* tex = X[4 + a];
      const float* o = c.O.row(1 + a);
      for (size_t j = 0; j < n; ++j) (*rgb)(a, static_cast<Eigen::Index>(j)) = tex[j] + o[j];
    }
  }
}

void NeuralField::backward(Cache& c, const Eigen::VectorXf& d_sdf, const Eigen::Matrix3Xf& d_rgb,
                           std::vector<float>& grad, TouchedNodes* touched) const {
  const size_t n = c.X.points();
  const int in0 = inputWidth(), enc = encodingWidth();
  const bool color = d_rgb.cols() == static_cast<Eigen::Index>(n);
  c.dO.resize(4, n);
  c.dO.setZero();  // the pads stay zero: they add nothing to any sum
  for (size_t j = 0; j < n; ++j) c.dO.row(0)[j] = mu_ * d_sdf[static_cast<Eigen::Index>(j)];
  if (color) {
    for (int a = 0; a < 3; ++a) {
      float* row = c.dO.row(1 + a);
      for (size_t j = 0; j < n; ++j) row[j] = d_rgb(a, static_cast<Eigen::Index>(j));
    }
  }
  denseBackward(params_.data() + w2_, 4, hidden_, c.H, c.dO, grad.data() + w2_, grad.data() + b2_, &c.dH);
  scaleBySlope(c.dH, c.S1);  // dA1 = dH * softplus'(A1)
  // The encoding has no parameters: only z's rows of the input gradient.
  denseBackward(params_.data() + w1_, hidden_, fuse_ + enc, c.Zin, c.dH, grad.data() + w1_, grad.data() + b1_, &c.dZ,
                fuse_);
  scaleBySlope(c.dZ, c.S0);  // dA0 = dZ * softplus'(A0)
  denseBackward(params_.data() + wf_, fuse_, in0, c.X, c.dZ, grad.data() + wf_, grad.data() + bf_, &c.dX);
  const float* dX[kCoarseChannels + 1];
  for (int ch = 0; ch <= kCoarseChannels; ++ch) dX[ch] = c.dX.row(ch);

  float* g_fine = grad.data() + fineOffset();
  const auto fine_base = static_cast<int32_t>(coarse_.nodeCount());
  dispatchAvx2Fma([&]() HXMAP_LAMBDA_INLINE_IN_CLONES {
    for (size_t j = 0; j < n; ++j) {
      const Corners& cc = c.coarse[j];
      const Corners& fc = c.fine[j];
      const float ds = mu_ * d_sdf[static_cast<Eigen::Index>(j)];
      Lanes g{};  // the coarse channels' gradients (the unused eighth stays 0)
      for (int ch = 0; ch < kCoarseChannels; ++ch) g[ch] = dX[ch][j];
      g[0] += ds;
      if (color) {
        for (int a = 0; a < 3; ++a) g[4 + a] += d_rgb(a, static_cast<Eigen::Index>(j));
      }
      const float g_s = dX[kCoarseChannels][j] + ds;
      for (int k = 0; k < 8; ++k) {
        float* q = grad.data() + static_cast<size_t>(cc.node[k]) * kCoarseStride;
        Lanes node;
        loadLanes(node, q);
        node += cc.weight[k] * g;
        storeLanes(q, node);
        g_fine[fc.node[k]] += fc.weight[k] * g_s;
      }
      if (touched) {
        for (int k = 0; k < 8; ++k) {
          touched->add(cc.node[k]);
          touched->add(fine_base + fc.node[k]);
        }
      }
    }
  });
}

}  // namespace hxmap::alg
