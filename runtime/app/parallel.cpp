#include "parallel.hpp"

#include <memory>

#ifdef HXMAP_HAVE_TBB
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#endif

namespace hxmap::rt {

ParallelFor makeParallelFor(int threads) {
  if (threads == 1) return serialFor;
#ifdef HXMAP_HAVE_TBB
  auto arena = threads > 0 ? std::make_shared<tbb::task_arena>(threads) : std::make_shared<tbb::task_arena>();
  return [arena](size_t n, const std::function<void(size_t, size_t)>& body) {
    if (n == 0) return;
    arena->execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n, std::max<size_t>(1, n / 64)),
                        [&](const tbb::blocked_range<size_t>& r) { body(r.begin(), r.end()); });
    });
  };
#else
  return serialFor;
#endif
}

}  // namespace hxmap::rt
