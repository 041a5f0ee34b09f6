// The decoder's dense layers over a batch of points.
//
// DESIGN: a batch is stored as rows of per-point values (PointRows: one
// contiguous row per feature, the points padded to a multiple of
// kPointLanes), so that every loop of a layer runs over points in vector
// lanes: 8 points per AVX2 register, where Eigen's matrix products over
// one column per point ran on SSE without fused multiply-adds (the build
// is portable; Eigen picks its instruction set at compile time, per
// translation unit). The kernels are built twice, for the baseline and
// for AVX2 with FMA, and the CPU picks (hxmap/core/simd.hpp). A layer of
// 8 to 23 inputs and 4 to 16 outputs over 6,000 points is a few hundred
// thousand multiply-adds: the loops keep 4 outputs' sums in registers
// and read each input row once per 4 outputs.
#pragma once

#include <cstddef>
#include <cstring>
#include <vector>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

/// Points per vector lane group: rows are padded to a multiple of this.
inline constexpr size_t kPointLanes = 8;

/// 8 floats (8 points' values of a row, or 8 channels of a grid node): one
/// AVX2 register, or two SSE / NEON registers (GCC / Clang vector
/// extensions).
using Lanes = float __attribute__((vector_size(4 * kPointLanes)));
/// (By reference: a vector returned by value changes the ABI with AVX.)
HXMAP_INLINE_IN_CLONES void loadLanes(Lanes& v, const float* p) { std::memcpy(&v, p, sizeof v); }
HXMAP_INLINE_IN_CLONES void storeLanes(float* p, const Lanes& v) { std::memcpy(p, &v, sizeof v); }

/// Rows of per-point values, each row contiguous and padded to a multiple
/// of kPointLanes points. The pad holds finite values (the producers
/// write it; the layers keep it finite), and a gradient's pad is zero.
class PointRows {
 public:
  /// rows x points; keeps the allocation when it is large enough. The
  /// contents are unspecified until written.
  void resize(int rows, size_t points);
  /// Sets every value, pad included, to zero.
  void setZero();
  int rows() const { return rows_; }
  size_t points() const { return points_; }
  size_t stride() const { return stride_; }  ///< points, padded
  float* row(int r) { return data_.data() + static_cast<size_t>(r) * stride_; }
  const float* row(int r) const { return data_.data() + static_cast<size_t>(r) * stride_; }
  float* data() { return data_.data(); }
  const float* data() const { return data_.data(); }
  size_t size() const { return static_cast<size_t>(rows_) * stride_; }

 private:
  std::vector<float> data_;
  int rows_ = 0;
  size_t points_ = 0, stride_ = 0;
};

/// Y = W X + b (b per output row) for `out` outputs and the first `in`
/// rows of X; W is out x in, column-major. Y is resized to out rows.
void denseForward(const float* W, const float* b, int out, int in, const PointRows& X, PointRows& Y);

/// Accumulates dW += dY X^T (the first `in` rows of X) and db += dY's row
/// sums, and, when dX is not null, sets dX to the first dx_rows rows of
/// W^T dY (all `in` when negative). Zero pads in dY keep them out of
/// every sum.
void denseBackward(const float* W, int out, int in, const PointRows& X, const PointRows& dY, float* dW, float* db,
                   PointRows* dX, int dx_rows = -1);

}  // namespace hxmap::alg
