#include "hxmap/tracking/icp_kernels.hpp"

#include <algorithm>
#include <cmath>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

// Built for AVX2 and for the baseline on x86-64 (picked at load time); plain
// loops the compiler vectorizes elsewhere (NEON on arm64).

HXMAP_SIMD_CLONES void projectFramePoints(const float* px, const float* py, const float* pz, const float* nx,
                                          const float* ny, const float* nz, int m, const RigidF& T, const RigidF& T_ref,
                                          const float k[4], int mw, int mh, GeometricProjection& out) {
  const float wf = static_cast<float>(mw), hf = static_cast<float>(mh);
  for (int i = 0; i < m; ++i) {
    const float a = px[i], b = py[i], c = pz[i];
    const float rx = T_ref.row(0, a, b, c), ry = T_ref.row(1, a, b, c), rz = T_ref.row(2, a, b, c);
    const float inv_z = rz > 0.0f ? 1.0f / rz : 0.0f;
    const float fu = k[0] * rx * inv_z + k[2] + 0.5f, fv = k[1] * ry * inv_z + k[3] + 0.5f;
    out.u[i] = fu;
    out.v[i] = fv;
    out.ok[i] = rz > 0.0f && fu >= 0.0f && fu < wf && fv >= 0.0f && fv < hf;
    for (int j = 0; j < 3; ++j) {
      out.x[j][i] = T.row(j, a, b, c);
      out.n[j][i] = T.row(j, nx[i], ny[i], nz[i], false);
    }
  }
}

HXMAP_SIMD_CLONES void geometricRows(int k, float huber, GeometricRows& g) {
  for (int i = 0; i < k; ++i) {
    const float dx = g.x[0][i] - g.q[0][i], dy = g.x[1][i] - g.q[1][i], dz = g.x[2][i] - g.q[2][i];
    const float nx = g.n[0][i], ny = g.n[1][i], nz = g.n[2][i];
    const float r = nx * dx + ny * dy + nz * dz;
    const float ar = std::abs(r);
    g.w[i] *= ar <= huber ? 1.0f : huber / ar;
    g.r[i] = r;
    // d r / d xi = (x x n, n) for a left perturbation of T.
    g.J[0][i] = g.x[1][i] * nz - g.x[2][i] * ny;
    g.J[1][i] = g.x[2][i] * nx - g.x[0][i] * nz;
    g.J[2][i] = g.x[0][i] * ny - g.x[1][i] * nx;
    g.J[3][i] = nx;
    g.J[4][i] = ny;
    g.J[5][i] = nz;
  }
}

HXMAP_SIMD_CLONES void projectRefPoints(const float* x, const float* y, const float* z, int m, const RigidF& T,
                                        const float k[4], float W, float H, PhotometricProjection& out) {
  for (int i = 0; i < m; ++i) {
    const float a = x[i], b = y[i], c = z[i];
    const float px = T.row(0, a, b, c), py = T.row(1, a, b, c), pz = T.row(2, a, b, c);
    const float inv_z = pz > 0.05f ? 1.0f / pz : 0.0f;
    const float uu = k[0] * px * inv_z + k[2], vv = k[1] * py * inv_z + k[3];
    out.p[0][i] = px;
    out.p[1][i] = py;
    out.p[2][i] = pz;
    out.inv_z[i] = inv_z;
    out.u[i] = uu;
    out.v[i] = vv;
    out.ok[i] = pz > 0.05f && uu >= 0.0f && vv >= 0.0f && uu < W && vv < H;
  }
}

HXMAP_SIMD_CLONES void photometricRows(int n, const float R[9], float fx, float fy, float scale, float huber,
                                       PhotometricRows& g) {
  for (int i = 0; i < n; ++i) {
    const float gx = g.gx[i], gy = g.gy[i], inv_z = g.inv_z[i];
    // d r / d p_cur = g * d pi / d p.
    const float d0 = gx * fx * inv_z, d1 = gy * fy * inv_z;
    const float d2 = -(gx * fx * g.p[0][i] + gy * fy * g.p[1][i]) * inv_z * inv_z;
    // p_cur = T^-1 y; left perturbation of T gives d r / d omega = (a x y)^T,
    // d r / d v = -a^T with a = R (d r / d p_cur).
    const float a0 = R[0] * d0 + R[1] * d1 + R[2] * d2;
    const float a1 = R[3] * d0 + R[4] * d1 + R[5] * d2;
    const float a2 = R[6] * d0 + R[7] * d1 + R[8] * d2;
    const float y0 = g.y[0][i], y1 = g.y[1][i], y2 = g.y[2][i];
    g.J[0][i] = scale * (a1 * y2 - a2 * y1);
    g.J[1][i] = scale * (a2 * y0 - a0 * y2);
    g.J[2][i] = scale * (a0 * y1 - a1 * y0);
    g.J[3][i] = -scale * a0;
    g.J[4][i] = -scale * a1;
    g.J[5][i] = -scale * a2;
    const float ar = std::abs(g.r[i]);
    g.w[i] *= ar <= huber ? 1.0f : huber / ar;
    g.clipped[i] = std::min(ar, 3.0f * huber);
    g.r[i] *= scale;
  }
}

}  // namespace hxmap::alg
