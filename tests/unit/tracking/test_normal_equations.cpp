// Tracking's reduction (J^T W J, J^T W r over float columns, vectorized by
// the compiler on every target) against the plain double-precision sum.
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "hxmap/tracking/normal_equations.hpp"

namespace hxmap::alg {
namespace {

TEST(NormalEquations, AgreeWithThePlainSumForAnyNumberOfRows) {
  std::mt19937 rng(7);
  // Values of the ranges tracking sees: Jacobians of a point 0.5-4 m away
  // (rotation part) and unit normals, Huber/confidence weights, residuals of
  // a few centimetres.
  std::uniform_real_distribution<float> jr(-4.0f, 4.0f), jt(-1.0f, 1.0f), wd(0.0f, 1.0f), rd(-0.05f, 0.05f);
  for (const int n : {0, 1, 7, 8, 9, 63, 64, 65, 200, 1000}) {
    const int room = (n + 7) / 8 * 8 + 8;
    std::vector<float> J[6], w(room), r(room);
    for (auto& c : J) c.assign(room, 0.0f);
    Matrix6d H_ref = Matrix6d::Zero();
    Vector6d b_ref = Vector6d::Zero();
    for (int s = 0; s < n; ++s) {
      Vector6d j;
      for (int i = 0; i < 6; ++i) j[i] = J[i][s] = i < 3 ? jr(rng) : jt(rng);
      w[s] = wd(rng);
      r[s] = rd(rng);
      H_ref += double(w[s]) * j * j.transpose();
      b_ref += double(w[s]) * double(r[s]) * j;
    }
    // Padding beyond n holds garbage: addColumns must not read it as rows.
    for (int s = n; s < room; ++s) {
      for (auto& c : J) c[s] = 1e6f;
      w[s] = r[s] = 1e6f;
    }
    NormalEquations eq;
    float* const cols[6] = {J[0].data(), J[1].data(), J[2].data(), J[3].data(), J[4].data(), J[5].data()};
    eq.addColumns(cols, w.data(), r.data(), n);
    // Float products summed in float lanes of up to 64 rows: relative error
    // of order 1e-6 of the sum of magnitudes.
    const double scale_H = std::max(1.0, H_ref.cwiseAbs().maxCoeff());
    const double scale_b = std::max(1e-3, b_ref.cwiseAbs().maxCoeff());
    EXPECT_LT((eq.H() - H_ref).cwiseAbs().maxCoeff(), 2e-5 * scale_H) << n << " rows";
    EXPECT_LT((eq.b() - b_ref).cwiseAbs().maxCoeff(), 2e-5 * scale_b) << n << " rows";
    EXPECT_TRUE(eq.H().isApprox(eq.H().transpose())) << n << " rows";
  }
}

}  // namespace
}  // namespace hxmap::alg
