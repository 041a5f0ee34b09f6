// The arithmetic passes of tracking's two terms: for a batch of points, the
// transforms and projections (pass 1) and the residuals, weights and
// Jacobian rows of the associations that passed (pass 3). Pass 2, the image
// reads and tests, stays with the callers in icp.cpp. Internal to the
// tracking module; in a header of their own so that tests can hold each
// kernel against its plain definition on every architecture.
#pragma once

#include <Eigen/Geometry>

namespace hxmap::alg {

// Points are processed kPointBatch at a time in three passes: the
// arithmetic that every point needs (transform, projection) across the
// batch, then the image reads and tests point by point (gathers, which do
// not vectorize), packing the survivors, then their Jacobians across the
// packed batch. DESIGN: one pass per point, with the arithmetic between
// the reads, kept every lane but one idle; split, the two arithmetic passes
// vectorize at the baseline instruction set (and twice as wide where the
// CPU has AVX2).
constexpr int kPointBatch = 128;

// A 3x4 rigid transform as plain floats: R row-major, then t.
struct RigidF {
  float r[9], t[3];
  explicit RigidF(const Eigen::Isometry3f& T) {
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) r[3 * i + j] = T.linear()(i, j);
      t[i] = T.translation()(i);
    }
  }
  /// Row i of R (a, b, c)^T, plus t_i when `translate`.
  float row(int i, float a, float b, float c, bool translate = true) const {
    return r[3 * i] * a + r[3 * i + 1] * b + r[3 * i + 2] * c + (translate ? t[i] : 0.0f);
  }
};

// Pass 1 of the point-to-plane term: points [0, m) in the world (x),
// their normals rotated into it (n) and the model pixel each projects to
// (u, v: truncated, the nearest; ok where inside the image and in front).
struct GeometricProjection {
  alignas(32) float x[3][kPointBatch], n[3][kPointBatch], u[kPointBatch], v[kPointBatch];
  alignas(32) int ok[kPointBatch];
};

void projectFramePoints(const float* px, const float* py, const float* pz, const float* nx, const float* ny,
                        const float* nz, int m, const RigidF& T, const RigidF& T_ref, const float k[4], int mw, int mh,
                        GeometricProjection& out);

// Pass 2 packs the associations (world point x, model point q and normal
// n, weight so far, depth); pass 3 turns them into rows.
struct GeometricRows {
  alignas(32) float x[3][kPointBatch], q[3][kPointBatch], n[3][kPointBatch];
  alignas(32) float w[kPointBatch], z[kPointBatch];
  alignas(32) float J[6][kPointBatch], r[kPointBatch];
};

void geometricRows(int k, float huber, GeometricRows& g);

// Pass 1 of the photometric term: reference points [0, m) in the current
// camera (p), 1/z, and their pixel position (u, v) where it is inside the
// image (with a pixel to spare for interpolation) and in front (ok).
struct PhotometricProjection {
  alignas(32) float p[3][kPointBatch], inv_z[kPointBatch], u[kPointBatch], v[kPointBatch];
  alignas(32) int ok[kPointBatch];
};

void projectRefPoints(const float* x, const float* y, const float* z, int m, const RigidF& T, const float k[4], float W,
                      float H, PhotometricProjection& out);

// Pass 2 packs the warped points that pass (intensity gradient g, residual
// r, camera point p, 1/z, world point y, confidence); pass 3 turns them
// into rows.
struct PhotometricRows {
  alignas(32) float gx[kPointBatch], gy[kPointBatch], r[kPointBatch], p[2][kPointBatch], inv_z[kPointBatch];
  alignas(32) float y[3][kPointBatch], w[kPointBatch];
  alignas(32) float J[6][kPointBatch], clipped[kPointBatch];
};

void photometricRows(int n, const float R[9], float fx, float fy, float scale, float huber, PhotometricRows& g);

}  // namespace hxmap::alg
