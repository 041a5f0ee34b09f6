// The reduction at the heart of tracking: the Gauss-Newton system of
// 6-dof residuals, accumulated in a form the compiler vectorizes on every
// target (SSE or AVX2 on x86-64, NEON on arm64). Internal to the tracking
// module; in a header of its own so that a test can hold it against a plain
// sum on every architecture.
#pragma once

#include <algorithm>

#include "hxmap/geometry/se3.hpp"

namespace hxmap::alg {

// J^T W J and J^T W r of 6-dof residuals. DESIGN: rows come as columns
// (structure of arrays, a batch of points at a time) and are reduced
// product by product across 8 independent float lanes, kBatch rows at a
// time, a loop the compiler vectorizes at the baseline instruction set
// without reassociating any sum; each kBatch is added into double. Adding
// each row into 27 scalar float sums cost about twice as much per residual
// (it was a quarter of tracking).
class NormalEquations {
 public:
  /// Adds rows [0, n) given as columns (J_i, w, r), each with room for n
  /// rounded up to a multiple of 8: that padding is overwritten with
  /// zero-weight rows.
  void addColumns(float* const J[6], float* w, float* r, int n) {
    const int padded = (n + kLanes - 1) / kLanes * kLanes;
    for (int s = n; s < padded; ++s) {
      for (int i = 0; i < 6; ++i) J[i][s] = 0.0f;
      w[s] = r[s] = 0.0f;
    }
    alignas(32) float wj[6][kBatch];
    for (int s0 = 0; s0 < padded; s0 += kBatch) {
      const int m = std::min(kBatch, padded - s0);
      for (int i = 0; i < 6; ++i) {
        for (int s = 0; s < m; ++s) wj[i][s] = w[s0 + s] * J[i][s0 + s];
      }
      int k = 0;
      for (int i = 0; i < 6; ++i) {
        for (int j = i; j < 6; ++j) H_[k++] += dot(wj[i], J[j] + s0, m);
        b_[i] += dot(wj[i], r + s0, m);
      }
    }
  }
  /// Both triangles.
  Matrix6d H() const {
    Matrix6d H;
    int k = 0;
    for (int i = 0; i < 6; ++i) {
      for (int j = i; j < 6; ++j) H(i, j) = H(j, i) = H_[k++];
    }
    return H;
  }
  Vector6d b() const { return Vector6d(b_); }
  void merge(const NormalEquations& o) {
    for (int k = 0; k < 21; ++k) H_[k] += o.H_[k];
    for (int i = 0; i < 6; ++i) b_[i] += o.b_[i];
  }

 private:
  static constexpr int kBatch = 64, kLanes = 8;

  static double dot(const float* a, const float* b, int n) {
    float lane[kLanes] = {};
    for (int s = 0; s < n; s += kLanes) {
      for (int l = 0; l < kLanes; ++l) lane[l] += a[s + l] * b[s + l];
    }
    double sum = 0;
    for (float x : lane) sum += x;
    return sum;
  }

  double H_[21] = {}, b_[6] = {};
};

}  // namespace hxmap::alg
