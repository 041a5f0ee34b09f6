// Tracking's arithmetic kernels (vectorized by the compiler: SSE or AVX2 on
// x86-64, NEON on arm64) against their plain definitions in double: the
// projections against the pinhole model, the residuals against the terms'
// formulas, and the Jacobian rows against finite differences of the residual
// under a left perturbation of the camera pose.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "hxmap/tracking/icp_kernels.hpp"

namespace hxmap::alg {
namespace {

using Vec3 = Eigen::Vector3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;

// exp(xi) T to first order and beyond (rotation exactly), xi = (omega, v).
Eigen::Isometry3d perturbed(const Vec6& xi, const Eigen::Isometry3d& T) {
  Eigen::Isometry3d E = Eigen::Isometry3d::Identity();
  const Vec3 w = xi.head<3>();
  if (w.norm() > 0) E.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  E.translation() = xi.tail<3>();
  return E * T;
}

Eigen::Isometry3d randomPose(std::mt19937& rng, double angle, double shift) {
  std::normal_distribution<double> g(0.0, 1.0);
  const Vec3 axis = Vec3(g(rng), g(rng), g(rng)).normalized();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
  T.translation() = shift * Vec3(g(rng), g(rng), g(rng));
  return T;
}

// Central differences of f(xi) at 0, one coordinate at a time.
template <class F>
Vec6 numericGradient(const F& f) {
  const double h = 1e-6;
  Vec6 J;
  for (int i = 0; i < 6; ++i) {
    Vec6 d = Vec6::Zero();
    d[i] = h;
    J[i] = (f(d) - f(-d)) / (2 * h);
  }
  return J;
}

// A kernel's pixel (u, v, ok) against the true one (u, v) in a w x h
// image: ok exactly when inside (pixels on the edge within float rounding
// may go either way), the position where inside. Counts the pixels inside.
template <class Projection>
void expectPixel(const Projection& proj, int i, double u, double v, double w, double h, int& inside) {
  const double edge = std::min({u, w - u, v, h - v});
  if (std::abs(edge) < 1e-2) return;
  EXPECT_EQ(proj.ok[i] != 0, edge > 0) << i;
  if (edge > 0) {
    ++inside;
    EXPECT_NEAR(proj.u[i], u, 2e-3) << i;
    EXPECT_NEAR(proj.v[i], v, 2e-3) << i;
  }
}

TEST(IcpKernels, PointToPlaneProjectionAndRowsAgreeWithTheirDefinition) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> xy(-0.8f, 0.8f), depth(-0.2f, 4.0f), unit(-1.0f, 1.0f), weight(0.1f, 1.0f);
  const Eigen::Isometry3d T = randomPose(rng, 0.4, 0.5), T_ref = randomPose(rng, 0.05, 0.05);
  const float k[4] = {525.0f, 521.0f, 319.5f, 239.5f};
  const int mw = 640, mh = 480;
  const int m = 100;
  std::vector<float> px(m), py(m), pz(m), nx(m), ny(m), nz(m);
  for (int i = 0; i < m; ++i) {
    pz[i] = depth(rng);
    px[i] = xy(rng) * std::abs(pz[i]);
    py[i] = xy(rng) * std::abs(pz[i]);
    const Vec3 n = Vec3(unit(rng), unit(rng), unit(rng)).normalized();
    nx[i] = float(n.x()), ny[i] = float(n.y()), nz[i] = float(n.z());
  }
  GeometricProjection proj;
  projectFramePoints(px.data(), py.data(), pz.data(), nx.data(), ny.data(), nz.data(), m, RigidF(T.cast<float>()),
                     RigidF(T_ref.cast<float>()), k, mw, mh, proj);
  int inside = 0;
  for (int i = 0; i < m; ++i) {
    const Vec3 p(px[i], py[i], pz[i]), n(nx[i], ny[i], nz[i]);
    const Vec3 x = T * p, nw = T.linear() * n, r = T_ref * p;
    for (int j = 0; j < 3; ++j) {
      EXPECT_NEAR(proj.x[j][i], x[j], 1e-5 * (1 + x.norm())) << i;
      EXPECT_NEAR(proj.n[j][i], nw[j], 1e-6) << i;
    }
    if (r.z() <= 1e-3) {
      EXPECT_EQ(proj.ok[i], 0) << "behind the model camera: " << i;
      continue;
    }
    expectPixel(proj, i, k[0] * r.x() / r.z() + k[2] + 0.5, k[1] * r.y() / r.z() + k[3] + 0.5, mw, mh, inside);
  }
  EXPECT_GT(inside, m / 4);
  EXPECT_LT(inside, m);

  // Rows: r = n . (x - q) for the model point q and normal n, its Huber
  // weight, and d r / d xi for x -> exp(xi) x.
  GeometricRows rows;
  const float huber = 0.01f;
  for (int i = 0; i < m; ++i) {
    const Vec3 n = Vec3(unit(rng), unit(rng), unit(rng)).normalized();
    for (int j = 0; j < 3; ++j) {
      rows.x[j][i] = xy(rng);
      rows.n[j][i] = float(n[j]);
      rows.q[j][i] = rows.x[j][i] + 0.02f * unit(rng);
    }
    rows.w[i] = weight(rng);
    rows.z[i] = 1.0f;
  }
  GeometricRows in = rows;
  geometricRows(m, huber, rows);
  int clipped = 0;
  for (int i = 0; i < m; ++i) {
    const Vec3 x(in.x[0][i], in.x[1][i], in.x[2][i]), q(in.q[0][i], in.q[1][i], in.q[2][i]);
    const Vec3 n(in.n[0][i], in.n[1][i], in.n[2][i]);
    const double r = n.dot(x - q);
    EXPECT_NEAR(rows.r[i], r, 1e-6) << i;
    const double w = in.w[i] * (std::abs(r) <= huber ? 1.0 : huber / std::abs(r));
    clipped += std::abs(r) > huber;
    EXPECT_NEAR(rows.w[i], w, 1e-6) << i;
    const Vec6 J =
        numericGradient([&](const Vec6& xi) { return n.dot(perturbed(xi, Eigen::Isometry3d::Identity()) * x - q); });
    for (int j = 0; j < 6; ++j) EXPECT_NEAR(rows.J[j][i], J[j], 1e-5) << i << " J" << j;
  }
  EXPECT_GT(clipped, 0);
  EXPECT_LT(clipped, m);
}

TEST(IcpKernels, PhotometricProjectionAndRowsAgreeWithTheirDefinition) {
  std::mt19937 rng(12);
  std::uniform_real_distribution<float> xy(-0.8f, 0.8f), depth(0.0f, 4.0f), unit(-1.0f, 1.0f), weight(0.1f, 1.0f);
  const Eigen::Isometry3d T_world_cam = randomPose(rng, 0.4, 0.5);
  const Eigen::Isometry3d T_cur_world = T_world_cam.inverse();
  const float fx = 525.0f, fy = 521.0f, cx = 319.5f, cy = 239.5f;
  const float k[4] = {fx, fy, cx, cy};
  const float W = 638.0f, H = 478.0f;
  const int m = 100;
  std::vector<float> yx(m), yy(m), yz(m);
  for (int i = 0; i < m; ++i) {  // world points, made from camera points
    const float z = depth(rng);
    const Vec3 y = T_world_cam * Vec3(xy(rng) * z, xy(rng) * z, z);
    yx[i] = float(y.x()), yy[i] = float(y.y()), yz[i] = float(y.z());
  }
  PhotometricProjection proj;
  projectRefPoints(yx.data(), yy.data(), yz.data(), m, RigidF(T_cur_world.cast<float>()), k, W, H, proj);
  int inside = 0;
  for (int i = 0; i < m; ++i) {
    const Vec3 p = T_cur_world * Vec3(yx[i], yy[i], yz[i]);
    for (int j = 0; j < 3; ++j) EXPECT_NEAR(proj.p[j][i], p[j], 1e-5 * (1 + p.norm())) << i;
    if (std::abs(p.z() - 0.05) < 1e-4) continue;
    if (p.z() < 0.05) {
      EXPECT_EQ(proj.ok[i], 0) << "too near: " << i;
      EXPECT_EQ(proj.inv_z[i], 0.0f) << i;
      continue;
    }
    EXPECT_NEAR(proj.inv_z[i], 1 / p.z(), 1e-5 / p.z()) << i;
    expectPixel(proj, i, fx * p.x() / p.z() + cx, fy * p.y() / p.z() + cy, W, H, inside);
  }
  EXPECT_GT(inside, m / 4);
  EXPECT_LT(inside, m);

  // Rows: the intensity residual linearized at the warped pixel,
  // r(xi) = g . pi((exp(xi) T_world_cam)^-1 y) + const, scaled by `scale`,
  // its Huber weight on the unscaled residual, and that residual clipped.
  float R[9];
  for (int i = 0; i < 9; ++i) R[i] = float(T_world_cam.linear()(i / 3, i % 3));
  PhotometricRows rows;
  const float scale = 0.2f, huber = 0.05f;
  const int n = 80;
  std::vector<Vec3> ys(n);
  for (int i = 0; i < n; ++i) {
    const float z = 0.5f + depth(rng);
    const Vec3 pc(xy(rng) * z, xy(rng) * z, z);
    const Vec3 y = T_world_cam * pc;
    ys[i] = Vec3(float(y.x()), float(y.y()), float(y.z()));
    const Vec3 p = T_cur_world * ys[i];
    rows.gx[i] = 2.0f * unit(rng);
    rows.gy[i] = 2.0f * unit(rng);
    rows.r[i] = 0.1f * unit(rng);
    rows.p[0][i] = float(p.x());
    rows.p[1][i] = float(p.y());
    rows.inv_z[i] = float(1 / p.z());
    for (int j = 0; j < 3; ++j) rows.y[j][i] = float(ys[i][j]);
    rows.w[i] = weight(rng);
  }
  PhotometricRows in = rows;
  photometricRows(n, R, fx, fy, scale, huber, rows);
  int clipped = 0;
  for (int i = 0; i < n; ++i) {
    const double r = in.r[i], ar = std::abs(r);
    EXPECT_NEAR(rows.r[i], scale * r, 1e-7) << i;
    EXPECT_NEAR(rows.w[i], in.w[i] * (ar <= huber ? 1.0 : huber / ar), 1e-6) << i;
    EXPECT_NEAR(rows.clipped[i], std::min(ar, 3.0 * huber), 1e-7) << i;
    clipped += ar > huber;
    const Vec6 J = numericGradient([&](const Vec6& xi) {
      const Vec3 p = perturbed(xi, T_world_cam).inverse() * ys[i];
      return scale * (in.gx[i] * (fx * p.x() / p.z() + cx) + in.gy[i] * (fy * p.y() / p.z() + cy));
    });
    const double size = std::max(1.0, J.norm());
    for (int j = 0; j < 6; ++j) EXPECT_NEAR(rows.J[j][i], J[j], 1e-4 * size) << i << " J" << j;
  }
  EXPECT_GT(clipped, 0);
  EXPECT_LT(clipped, n);
}

}  // namespace
}  // namespace hxmap::alg
