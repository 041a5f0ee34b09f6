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

// log1p(y) for y in [0, 1], given s = y / (2 + y) (at most 1/3):
// log1p(y) = 2 atanh(s) = 2 s (1 + s^2 / 3 + s^4 / 5 + ...), the series to
// s^12 inside (the rest is below 1.5e-8 relative). No range split, and tiny
// y keep their relative accuracy (s = y / 2).
HXMAP_INLINE_IN_CLONES float log1pOfUnit(float s) {
  const float w = s * s, w2 = w * w, w4 = w2 * w2;
  const float a = 1.0f + w * (1.0f / 3.0f);
  const float b = 1.0f / 5.0f + w * (1.0f / 7.0f);
  const float c = 1.0f / 9.0f + w * (1.0f / 11.0f);
  const float p = (a + w2 * b) + w4 * (c + w2 * (1.0f / 13.0f));
  return 2.0f * s * p;
}

}  // namespace

float expNonPositive(float x) { return expNeg(x); }
float log1pUnit(float y) { return log1pOfUnit(y / (2.0f + y)); }

void softplusAndSlope(const float* a, float* sp, float* slope, size_t n) {
  dispatchAvx2Fma([=]() HXMAP_LAMBDA_INLINE_IN_CLONES {
    for (size_t i = 0; i < n; ++i) {
      const float x = a[i];
      const float e = expNeg(-std::abs(x));  // (0, 1]
      // 1 / (1 + e) and 1 / (2 + e) from one division.
      const float r = 1.0f / ((1.0f + e) * (2.0f + e));
      const float inv = (2.0f + e) * r;
      sp[i] = (x > 0.0f ? x : 0.0f) + log1pOfUnit(e * (1.0f + e) * r);
      slope[i] = x >= 0.0f ? inv : e * inv;
    }
  });
}

}  // namespace hxmap::alg
