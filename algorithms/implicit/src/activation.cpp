#include "hxmap/implicit/activation.hpp"

#include <bit>
#include <cmath>
#include <cstdint>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

namespace {

// Branch-free, so that a loop of them vectorizes; a NaN takes the clamp's
// bound (no float-to-int conversion of a NaN).
inline float expNeg(float x) {
  x = x > -86.0f ? x : -86.0f;  // e^-86 ~ 4e-38: the result stays a normal float
  x = x < 0.0f ? x : 0.0f;
  // x = n ln2 + r, |r| <= ln2 / 2; ln2 in two parts (Cody-Waite).
  const float t = x * 1.44269504088896341f;
  const auto n = static_cast<int32_t>(t - 0.5f);  // nearest, for t <= 0
  const auto fn = static_cast<float>(n);
  float r = x - fn * 0.693359375f;
  r = r - fn * -2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  const float er = p * (r * r) + r + 1.0f;
  return er * std::bit_cast<float>(static_cast<int32_t>((n + 127) * (1 << 23)));
}

inline float log1pOfUnit(float y) {
  const float u = 1.0f + y;  // (1, 2]
  const bool upper = u > 1.41421356f;
  const float z = upper ? 0.5f * u : u;  // [sqrt(1/2), sqrt(2)]
  const float e = upper ? 1.0f : 0.0f;
  const float x = z - 1.0f;  // exact
  const float x2 = x * x;
  float p = 7.0376836292e-2f;
  p = p * x - 1.1514610310e-1f;
  p = p * x + 1.1676998740e-1f;
  p = p * x - 1.2420140846e-1f;
  p = p * x + 1.4249322787e-1f;
  p = p * x - 1.6668057665e-1f;
  p = p * x + 2.0000714765e-1f;
  p = p * x - 2.4999993993e-1f;
  p = p * x + 3.3333331174e-1f;
  float l = p * x * x2;
  l += e * -2.12194440e-4f;
  l += -0.5f * x2;
  l = x + l;
  l += e * 0.693359375f;
  // log(u) is log(1 + y) of a rounded 1 + y; scaling by y / (u - 1) undoes
  // that rounding (u - 1 is exact), so tiny y keep their relative accuracy.
  const float d = u - 1.0f;
  return d > 0.0f ? l * (y / (d > 0.0f ? d : 1.0f)) : y;
}

}  // namespace

float expNonPositive(float x) { return expNeg(x); }
float log1pUnit(float y) { return log1pOfUnit(y); }

HXMAP_SIMD_CLONES void softplusAndSlope(const float* a, float* sp, float* slope, size_t n) {
  for (size_t i = 0; i < n; ++i) {
    const float x = a[i];
    const float e = expNeg(-std::abs(x));  // (0, 1]
    const float inv = 1.0f / (1.0f + e);
    sp[i] = (x > 0.0f ? x : 0.0f) + log1pOfUnit(e);
    slope[i] = x >= 0.0f ? inv : e * inv;
  }
}

}  // namespace hxmap::alg
