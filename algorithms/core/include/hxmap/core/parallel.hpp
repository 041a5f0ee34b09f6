// Data-parallel loops in algorithms/ go through a ParallelFor that the caller
// provides (runtime/ may pass a TBB-backed one); the default is serial, which
// keeps algorithms deterministic and free of threads of their own.
#pragma once

#include <cstddef>
#include <functional>

namespace hxmap {

/// Calls body(begin, end) over disjoint chunks covering [0, n). Implementations
/// may call body concurrently from several threads; body must be safe for that.
using ParallelFor = std::function<void(size_t n, const std::function<void(size_t, size_t)>& body)>;

inline void serialFor(size_t n, const std::function<void(size_t, size_t)>& body) {
  if (n > 0) body(0, n);
}

}  // namespace hxmap
