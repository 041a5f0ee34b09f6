#include "hxmap/implicit/dense.hpp"

#include <algorithm>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

namespace {

HXMAP_INLINE_IN_CLONES float laneSum(const Lanes& v) {
  float s = 0.0f;
  for (size_t k = 0; k < kPointLanes; ++k) s += v[k];
  return s;
}

// Y[o] = b[o] + sum_i W[o, i] X[i], 4 outputs at a time.
HXMAP_INLINE_IN_CLONES void forwardRows(const float* W, const float* b, int out, int in, const float* X, float* Y,
                                        size_t stride) {
  for (size_t j = 0; j < stride; j += kPointLanes) {
    int o = 0;
    for (; o + 4 <= out; o += 4) {
      Lanes a0 = Lanes{} + b[o], a1 = Lanes{} + b[o + 1], a2 = Lanes{} + b[o + 2], a3 = Lanes{} + b[o + 3];
      for (int i = 0; i < in; ++i) {
        Lanes x;
        loadLanes(x, X + static_cast<size_t>(i) * stride + j);
        const float* w = W + static_cast<size_t>(i) * out + o;
        a0 += w[0] * x, a1 += w[1] * x, a2 += w[2] * x, a3 += w[3] * x;
      }
      storeLanes(Y + static_cast<size_t>(o) * stride + j, a0);
      storeLanes(Y + static_cast<size_t>(o + 1) * stride + j, a1);
      storeLanes(Y + static_cast<size_t>(o + 2) * stride + j, a2);
      storeLanes(Y + static_cast<size_t>(o + 3) * stride + j, a3);
    }
    for (; o < out; ++o) {
      Lanes a = Lanes{} + b[o];
      for (int i = 0; i < in; ++i) {
        Lanes x;
        loadLanes(x, X + static_cast<size_t>(i) * stride + j);
        a += W[static_cast<size_t>(i) * out + o] * x;
      }
      storeLanes(Y + static_cast<size_t>(o) * stride + j, a);
    }
  }
}

// dW[o, i] += sum_j dY[o][j] X[i][j] and db[o] += sum_j dY[o][j]: for 4
// outputs and 2 inputs at a time, 8 sums in registers over all points.
HXMAP_INLINE_IN_CLONES void weightGradient(int out, int in, const float* X, const float* dY, size_t stride, float* dW,
                                           float* db) {
  for (int o = 0; o < out; o += 4) {
    const int no = std::min(4, out - o);
    for (int i = 0; i < in; i += 2) {
      const int ni = std::min(2, in - i);
      Lanes s[4][2] = {};
      for (size_t j = 0; j < stride; j += kPointLanes) {
        Lanes x[2] = {};
        for (int c = 0; c < ni; ++c) loadLanes(x[c], X + static_cast<size_t>(i + c) * stride + j);
        for (int r = 0; r < no; ++r) {
          Lanes y;
          loadLanes(y, dY + static_cast<size_t>(o + r) * stride + j);
          s[r][0] += y * x[0];
          s[r][1] += y * x[1];
        }
      }
      for (int r = 0; r < no; ++r) {
        for (int c = 0; c < ni; ++c) dW[static_cast<size_t>(i + c) * out + o + r] += laneSum(s[r][c]);
      }
    }
  }
  for (int o = 0; o < out; ++o) {
    Lanes s{};
    for (size_t j = 0; j < stride; j += kPointLanes) {
      Lanes y;
      loadLanes(y, dY + static_cast<size_t>(o) * stride + j);
      s += y;
    }
    db[o] += laneSum(s);
  }
}

// dX[i] = sum_o W[o, i] dY[o] for i < rows, 4 inputs at a time.
HXMAP_INLINE_IN_CLONES void inputGradient(const float* W, int out, int rows, const float* dY, float* dX,
                                          size_t stride) {
  for (size_t j = 0; j < stride; j += kPointLanes) {
    int i = 0;
    for (; i + 4 <= rows; i += 4) {
      Lanes a0{}, a1{}, a2{}, a3{};
      for (int o = 0; o < out; ++o) {
        Lanes y;
        loadLanes(y, dY + static_cast<size_t>(o) * stride + j);
        a0 += W[static_cast<size_t>(i) * out + o] * y;
        a1 += W[static_cast<size_t>(i + 1) * out + o] * y;
        a2 += W[static_cast<size_t>(i + 2) * out + o] * y;
        a3 += W[static_cast<size_t>(i + 3) * out + o] * y;
      }
      storeLanes(dX + static_cast<size_t>(i) * stride + j, a0);
      storeLanes(dX + static_cast<size_t>(i + 1) * stride + j, a1);
      storeLanes(dX + static_cast<size_t>(i + 2) * stride + j, a2);
      storeLanes(dX + static_cast<size_t>(i + 3) * stride + j, a3);
    }
    for (; i < rows; ++i) {
      Lanes a{};
      for (int o = 0; o < out; ++o) {
        Lanes y;
        loadLanes(y, dY + static_cast<size_t>(o) * stride + j);
        a += W[static_cast<size_t>(i) * out + o] * y;
      }
      storeLanes(dX + static_cast<size_t>(i) * stride + j, a);
    }
  }
}

}  // namespace

void PointRows::resize(int rows, size_t points) {
  rows_ = rows;
  points_ = points;
  stride_ = (points + kPointLanes - 1) / kPointLanes * kPointLanes;
  if (data_.size() < size()) data_.resize(size());
}

void PointRows::setZero() { std::fill(data_.begin(), data_.begin() + static_cast<std::ptrdiff_t>(size()), 0.0f); }

void denseForward(const float* W, const float* b, int out, int in, const PointRows& X, PointRows& Y) {
  Y.resize(out, X.points());
  const float* x = X.data();
  float* y = Y.data();
  const size_t stride = X.stride();
  dispatchAvx2Fma([=]() HXMAP_LAMBDA_INLINE_IN_CLONES { forwardRows(W, b, out, in, x, y, stride); });
}

void denseBackward(const float* W, int out, int in, const PointRows& X, const PointRows& dY, float* dW, float* db,
                   PointRows* dX, int dx_rows) {
  const int rows = dx_rows < 0 ? in : std::min(dx_rows, in);
  if (dX) dX->resize(rows, dY.points());
  const float* x = X.data();
  const float* dy = dY.data();
  float* dx = dX ? dX->data() : nullptr;
  const size_t stride = dY.stride();
  dispatchAvx2Fma([=]() HXMAP_LAMBDA_INLINE_IN_CLONES {
    weightGradient(out, in, x, dy, stride, dW, db);
    if (dx) inputGradient(W, out, rows, dy, dx, stride);
  });
}

}  // namespace hxmap::alg
