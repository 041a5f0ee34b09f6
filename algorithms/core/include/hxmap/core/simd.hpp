// Function multi-versioning for the few loops bound by arithmetic: a
// function declared HXMAP_SIMD_CLONES is built for AVX2 and for the
// baseline, and the loader picks the one the CPU runs.
// DESIGN: the build stays portable (no -march; HXMAP_NATIVE is for people
// building on the robot itself) while an x86 robot CPU with AVX2 gets twice
// the vector width where it pays (the depth filter: 1.8 -> 0.9 ms per TUM
// frame). Empty elsewhere: other CPUs and systems, and sanitizer builds
// (which test the same source through its baseline version).
#pragma once

// HXMAP_SANITIZED: a sanitizer build (GCC's or clang's).
#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
#define HXMAP_SANITIZED 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define HXMAP_SANITIZED 1
#endif

#if defined(__x86_64__) && defined(__linux__) && !defined(HXMAP_SANITIZED) && !defined(HXMAP_NO_SIMD_CLONES)
#define HXMAP_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
/// AVX2 with fused multiply-adds, for a function the caller picks at run
/// time (hxmap::cpuHasAvx2Fma()). DESIGN: target_clones takes one feature
/// per clone ("avx2" has no FMA) or an "arch=", and GCC inlines nothing
/// that is not always_inline into an "arch=" clone (std::bit_cast stayed a
/// call per element); target("avx2,fma") inlines what the baseline has.
/// For the refinement's kernels, whose results may differ from the
/// baseline's in the last bits. Code whose outputs must not depend on the
/// CPU (the TSDF fusion kernel) stays with HXMAP_SIMD_CLONES.
#define HXMAP_TARGET_AVX2_FMA __attribute__((target("avx2,fma")))
#define HXMAP_HAVE_AVX2_FMA_TARGET 1
/// For loops of __builtin_popcountll: the baseline x86-64 has no popcount
/// instruction (a library call per word instead).
#define HXMAP_POPCNT_CLONES __attribute__((target_clones("popcnt", "default")))
#else
#define HXMAP_SIMD_CLONES
#define HXMAP_POPCNT_CLONES
#endif

/// For the helpers a HXMAP_SIMD_CLONES function calls: inlined into each
/// clone, so that they are compiled for its target too. DESIGN: a helper
/// left out of line is one baseline function that every clone calls; GCC
/// kept the fusion kernel's row loop (a template) out of line, and its AVX2
/// clone was a call into baseline code. On a lambda the attribute goes
/// after the parameter list.
#if defined(__GNUC__)
#define HXMAP_INLINE_IN_CLONES __attribute__((always_inline)) inline
#define HXMAP_LAMBDA_INLINE_IN_CLONES __attribute__((always_inline))
#else
#define HXMAP_INLINE_IN_CLONES inline
#define HXMAP_LAMBDA_INLINE_IN_CLONES
#endif

namespace hxmap {

/// True where functions marked HXMAP_TARGET_AVX2_FMA may run (checked once).
inline bool cpuHasAvx2Fma() {
#if defined(HXMAP_HAVE_AVX2_FMA_TARGET)
  static const bool yes = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return yes;
#else
  return false;
#endif
}

#if defined(HXMAP_HAVE_AVX2_FMA_TARGET)
template <typename Body>
HXMAP_TARGET_AVX2_FMA void runForAvx2Fma(const Body& body) {
  body();
}
#endif

/// Runs body() compiled for AVX2 with FMA where the CPU has them, else for
/// the baseline: body is a lambda marked HXMAP_LAMBDA_INLINE_IN_CLONES
/// whose loops (and the HXMAP_INLINE_IN_CLONES helpers it calls) are
/// inlined, so each copy is vectorized for its target.
template <typename Body>
void dispatchAvx2Fma(const Body& body) {
#if defined(HXMAP_HAVE_AVX2_FMA_TARGET)
  if (cpuHasAvx2Fma()) {
    runForAvx2Fma(body);
    return;
  }
#endif
  body();
}

}  // namespace hxmap
