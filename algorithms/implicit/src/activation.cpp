#include "hxmap/implicit/activation.hpp"

#include <bit>
#include <cmath>
#include <cstdint>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

namespace {

// Branch-free, so that a loop of them vectorizes; a NaN takes the clamp's
// bound (no float-to-int conversion of a NaN).
HXMAP_INLINE_IN_CLONES float expNeg(float x) {
  x = x > -86.0f ? x : -86.0f;  // e^-86 ~ 4e-38: the result stays a normal float
  x = x < 0.0f ? x : 0.0f;
  // x = n ln2 + r, |r| <= ln2 / 2; ln2 in two parts (Cody-Waite).
  const float t = x * 1.44269504088896341f;
  const auto n = static_cast<int32_t>(t - 0.5f);  // nearest, for t <= 0
  const auto fn = static_cast<float>(n);
  float r = x - fn * 0.693359375f;
  r = r - fn * -2.12194440e-4f;
  // Estrin's scheme: three short chains instead of one of five steps (the
  // loop is bound by the polynomials' latency, not by their arithmetic).
  const float r2 = r * r;
  const float p01 = 5.0000001201e-1f + 1.6666665459e-1f * r;
  const float p23 = 4.1665795894e-2f + 8.3334519073e-3f * r;
  const float p45 = 1.3981999507e-3f + 1.9875691500e-4f * r;
  const float p = p01 + r2 * (p23 + r2 * p45);
  const float er = p * r2 + r + 1.0f;
  return er * std::bit_cast<float>(static_cast<int32_t>((n + 127) * (1 << 23)));
}

// log1p(y) for y in [0, 1], given inv_u = 1 / (1 + y).
HXMAP_INLINE_IN_CLONES float log1pOfUnit(float y, float inv_u) {
  const float u = 1.0f + y;  // (1, 2]
  const bool upper = u > 1.41421356f;
  const float z = upper ? 0.5f * u : u;  // [sqrt(1/2), sqrt(2)]
  const float e = upper ? 1.0f : 0.0f;
  const float x = z - 1.0f;  // exact
  const float x2 = x * x;
  const float x4 = x2 * x2;
  const float q01 = 3.3333331174e-1f - 2.4999993993e-1f * x;
  const float q23 = 2.0000714765e-1f - 1.6668057665e-1f * x;
  const float q45 = 1.4249322787e-1f - 1.2420140846e-1f * x;
  const float q67 = 1.1676998740e-1f - 1.1514610310e-1f * x;
  const float p = (q01 + x2 * q23) + x4 * ((q45 + x2 * q67) + x4 * 7.0376836292e-2f);
  float l = p * x * x2;
  l += e * -2.12194440e-4f;
  l += -0.5f * x2;
  l = x + l;
  l += e * 0.693359375f;
  // log(u) is log(1 + y) of a rounded 1 + y; adding (y - (u - 1)) / u
  // (u - 1 is exact) undoes that rounding to first order, so tiny y keep
  // their relative accuracy (y itself where 1 + y rounds to 1).
  return l + (y - (u - 1.0f)) * inv_u;
}

}  // namespace

float expNonPositive(float x) { return expNeg(x); }
float log1pUnit(float y) { return log1pOfUnit(y, 1.0f / (1.0f + y)); }

void softplusAndSlope(const float* a, float* sp, float* slope, size_t n) {
  dispatchAvx2Fma([=]() HXMAP_LAMBDA_INLINE_IN_CLONES {
    for (size_t i = 0; i < n; ++i) {
      const float x = a[i];
      const float e = expNeg(-std::abs(x));  // (0, 1]
      const float inv = 1.0f / (1.0f + e);
      sp[i] = (x > 0.0f ? x : 0.0f) + log1pOfUnit(e, inv);
      slope[i] = x >= 0.0f ? inv : e * inv;
    }
  });
}

}  // namespace hxmap::alg
