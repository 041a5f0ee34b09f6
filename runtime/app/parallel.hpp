// The ParallelFor handed to algorithms by the program (TBB when built with it).
#pragma once

#include "hxmap/core/parallel.hpp"

namespace hxmap::rt {

/// A data-parallel for over `threads` threads (0 = all cores, 1 = serial).
ParallelFor makeParallelFor(int threads);

}  // namespace hxmap::rt
