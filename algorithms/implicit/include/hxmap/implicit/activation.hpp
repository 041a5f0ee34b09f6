// The decoder's activation, softplus, and its slope, in one pass over a
// layer's pre-activations.
//
//   softplus(a) = log(1 + e^a) = max(a, 0) + log1p(e^-|a|)
//   slope(a)    = d softplus / da = sigmoid(a)
//               = 1 / (1 + e^-|a|)      for a >= 0
//               = e^-|a| / (1 + e^-|a|) for a <  0
//
// DESIGN: both come from the one exponential e^-|a| (in (0, 1], so nothing
// overflows), and the forward pass keeps the slope for the backward pass,
// which then needs no transcendental at all. The exponential is a
// polynomial (Cephes' single-precision expf coefficients, Cody-Waite range
// reduction), log1p(e) the series of 2 atanh(e / (2 + e)) (e / (2 + e) is
// at most 1/3: no range split), both evaluated by Estrin's scheme, and
// 1 / (1 + e) for the slope and 1 / (2 + e) come from one division; plain
// loops the compiler vectorizes (AVX2 with FMA where the CPU has them, SSE
// otherwise on x86-64, NEON on arm64): libm's scalar log1pf and expf were
// half of a refinement iteration's time.
// Accuracy: within 4e-7 relative of the double-precision definitions
// (worst seen 2.9e-7 for softplus, 1.9e-7 for the slope), and
// within e^-86 (~4.5e-38) absolute where they fall below that (tested in
// test_implicit).
#pragma once

#include <cstddef>

namespace hxmap::alg {

/// sp[i] = softplus(a[i]) and slope[i] = sigmoid(a[i]) for i < n (a may
/// alias neither output). Finite inputs give finite outputs.
void softplusAndSlope(const float* a, float* sp, float* slope, size_t n);

/// e^x for x <= 0 (clamped below at -86, so the result stays a normal
/// float): the building block above, exposed for its test.
float expNonPositive(float x);
/// log1p(y) for y in [0, 1].
float log1pUnit(float y);

}  // namespace hxmap::alg
