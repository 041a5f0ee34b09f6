#include "hxmap/implicit/neural_field.hpp"

#include <algorithm>
#include <cmath>

#include "hxmap/implicit/activation.hpp"

namespace hxmap::alg {

namespace {

using MapMat = Eigen::Map<Eigen::MatrixXf>;
using ConstMapMat = Eigen::Map<const Eigen::MatrixXf>;
using MapVec = Eigen::Map<Eigen::VectorXf>;
using ConstMapVec = Eigen::Map<const Eigen::VectorXf>;

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

}  // namespace

void denseForward(const float* W, const float* b, int out, int in, const Eigen::MatrixXf& X, Eigen::MatrixXf& Y) {
  const ConstMapMat Wm(W, out, in);
  Y.noalias() = Wm * X;
  Y.colwise() += ConstMapVec(b, out);
}

void denseBackward(const float* W, int out, int in, const Eigen::MatrixXf& X, const Eigen::MatrixXf& dY, float* dW,
                   float* db, Eigen::MatrixXf* dX, int dx_rows) {
  MapMat(dW, out, in).noalias() += dY * X.transpose();
  MapVec(db, out) += dY.rowwise().sum();
  if (dX) dX->noalias() = ConstMapMat(W, out, in).leftCols(dx_rows < 0 ? in : dx_rows).transpose() * dY;
}

namespace {

/// Y = softplus(A) and S = softplus'(A).
void activate(const Eigen::MatrixXf& A, Eigen::MatrixXf& Y, Eigen::MatrixXf& S) {
  Y.resize(A.rows(), A.cols());
  S.resize(A.rows(), A.cols());
  softplusAndSlope(A.data(), Y.data(), S.data(), static_cast<size_t>(A.size()));
}

}  // namespace

Corners locate(const GridLayout& grid, const Eigen::Vector3f& p) {
  Corners c;
  int base[3];
  float frac[3];
  for (int a = 0; a < 3; ++a) {
    const int n = grid.nodes[a];
    float q = (p[a] - grid.origin[a]) / grid.cell;
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

  coarse_ = GridLayout{lo, voxel_size_, voxel_count_, kCoarseChannels};
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
        float* v = &params_[n * kCoarseChannels];
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
          if (span > 0) g[a] = (params_[n1 * kCoarseChannels] - params_[n0 * kCoarseChannels]) / static_cast<float>(span);
        }
        const float len = g.norm();
        if (len > 1e-6f) {
          for (int a = 0; a < 3; ++a) params_[n * kCoarseChannels + 1 + a] = g[a] / len;
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

void NeuralField::encode(const Eigen::Vector3f& p, float* out) const {
  const Eigen::Vector3f q = (p - center_).cwiseProduct(inv_half_extent_);
  out[0] = q.x(), out[1] = q.y(), out[2] = q.z();
  float* o = out + 3;
  // The first octave from sin/cos, each next one by the double-angle rule.
  float sn[3], cs[3];
  for (int a = 0; a < 3; ++a) {
    sn[a] = std::sin(static_cast<float>(M_PI) * q[a]);
    cs[a] = std::cos(static_cast<float>(M_PI) * q[a]);
  }
  for (int f = 0; f < frequencies_; ++f) {
    for (int a = 0; a < 3; ++a) {
      *o++ = sn[a];
      *o++ = cs[a];
      const float s2 = 2.0f * sn[a] * cs[a];
      cs[a] = (cs[a] - sn[a]) * (cs[a] + sn[a]);
      sn[a] = s2;
    }
  }
}

void NeuralField::forward(const Eigen::Matrix3Xf& points, Eigen::VectorXf& sdf_m, Eigen::Matrix3Xf* rgb,
                          Cache* cache) const {
  const Eigen::Index n = points.cols();
  Cache local;
  Cache& c = cache ? *cache : local;
  const int in0 = inputWidth(), enc = encodingWidth();
  c.X.resize(in0, n);
  c.Zin.resize(fuse_ + enc, n);
  const bool keep = cache != nullptr;
  if (keep) {
    c.coarse.resize(static_cast<size_t>(n));
    c.fine.resize(static_cast<size_t>(n));
  }
  const float* fine = params_.data() + fineOffset();
  for (Eigen::Index j = 0; j < n; ++j) {
    const Eigen::Vector3f p = points.col(j);
    const Corners cc = locate(coarse_, p), fc = locate(fine_, p);
    float v[kCoarseChannels] = {0, 0, 0, 0, 0, 0, 0};
    for (int k = 0; k < 8; ++k) {
      const float* node = params_.data() + static_cast<size_t>(cc.node[k]) * kCoarseChannels;
      for (int ch = 0; ch < kCoarseChannels; ++ch) v[ch] += cc.weight[k] * node[ch];
    }
    float s_fine = 0;
    for (int k = 0; k < 8; ++k) s_fine += fc.weight[k] * fine[fc.node[k]];
    for (int ch = 0; ch < kCoarseChannels; ++ch) c.X(ch, j) = v[ch];
    c.X(kCoarseChannels, j) = s_fine;
    encode(p, c.Zin.col(j).data() + fuse_);
    if (keep) c.coarse[static_cast<size_t>(j)] = cc, c.fine[static_cast<size_t>(j)] = fc;
  }
  denseForward(params_.data() + wf_, params_.data() + bf_, fuse_, in0, c.X, c.A0);
  activate(c.A0, c.Z0, c.S0);
  c.Zin.topRows(fuse_) = c.Z0;
  denseForward(params_.data() + w1_, params_.data() + b1_, hidden_, fuse_ + enc, c.Zin, c.A1);
  activate(c.A1, c.H, c.S1);
  Eigen::MatrixXf O;
  denseForward(params_.data() + w2_, params_.data() + b2_, 4, hidden_, c.H, O);
  sdf_m = mu_ * (c.X.row(0) + c.X.row(kCoarseChannels) + O.row(0)).transpose();
  if (rgb) *rgb = c.X.middleRows(4, 3) + O.bottomRows(3);
}

void NeuralField::backward(const Cache& c, const Eigen::VectorXf& d_sdf, const Eigen::Matrix3Xf& d_rgb,
                           std::vector<float>& grad, std::vector<int32_t>* touched) const {
  const Eigen::Index n = c.X.cols();
  const int in0 = inputWidth(), enc = encodingWidth();
  const bool color = d_rgb.cols() == n;
  Eigen::MatrixXf dO = Eigen::MatrixXf::Zero(4, n);
  dO.row(0) = mu_ * d_sdf.transpose();
  if (color) dO.bottomRows(3) = d_rgb;
  Eigen::MatrixXf dH, dZin, dX;
  denseBackward(params_.data() + w2_, 4, hidden_, c.H, dO, grad.data() + w2_, grad.data() + b2_, &dH);
  const Eigen::MatrixXf dA1 = dH.cwiseProduct(c.S1);
  // The encoding has no parameters: only z's rows of the input gradient.
  denseBackward(params_.data() + w1_, hidden_, fuse_ + enc, c.Zin, dA1, grad.data() + w1_, grad.data() + b1_, &dZin,
                fuse_);
  const Eigen::MatrixXf dA0 = dZin.cwiseProduct(c.S0);
  denseBackward(params_.data() + wf_, fuse_, in0, c.X, dA0, grad.data() + wf_, grad.data() + bf_, &dX);
  dX.row(0) += mu_ * d_sdf.transpose();
  dX.row(kCoarseChannels) += mu_ * d_sdf.transpose();
  if (color) dX.middleRows(4, 3) += d_rgb;

  float* g_fine = grad.data() + fineOffset();
  const auto fine_base = static_cast<int32_t>(coarse_.nodeCount());
  for (Eigen::Index j = 0; j < n; ++j) {
    const Corners& cc = c.coarse[static_cast<size_t>(j)];
    const Corners& fc = c.fine[static_cast<size_t>(j)];
    for (int k = 0; k < 8; ++k) {
      float* node = grad.data() + static_cast<size_t>(cc.node[k]) * kCoarseChannels;
      for (int ch = 0; ch < kCoarseChannels; ++ch) node[ch] += cc.weight[k] * dX(ch, j);
      g_fine[fc.node[k]] += fc.weight[k] * dX(kCoarseChannels, j);
    }
    if (touched) {
      for (int k = 0; k < 8; ++k) {
        touched->push_back(cc.node[k]);
        touched->push_back(fine_base + fc.node[k]);
      }
    }
  }
}

}  // namespace hxmap::alg
