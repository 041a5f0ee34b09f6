// libFuzzer target: the dataset text parsers (TUM lists and trajectories,
// Replica's matrix trajectories) and the PLY reader. `bash .ci/fuzz` builds
// and runs every target (tests/fuzz/corpus/ holds their seeds).
#include <cstddef>
#include <cstdint>
#include <string>

#include "hxmap/dataset/parsers.hpp"
#include "hxmap/dataset/ply.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  for (bool skip : {false, true}) {
    const hxmap::drv::ParseOptions o{skip};
    (void)hxmap::drv::parseTumList(text, "fuzz", o);
    (void)hxmap::drv::parseTumTrajectory(text, "fuzz", o);
    (void)hxmap::drv::parseMatrixTrajectory(text, "fuzz", 33'333'333, o);
  }
  (void)hxmap::drv::parsePly(text, "fuzz");
  return 0;
}
