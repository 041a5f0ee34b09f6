// libFuzzer target: map files (hxmap run --load-map, hxmap map). Any input
// gives a map or an error, never a crash; a map holds no more blocks or
// keyframes than its header counts, with or without skipping bad records.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "hxmap/mapfile/map_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  for (const bool skip : {false, true}) {
    hxmap::drv::MapLoadOptions o;
    o.skip_bad = skip;
    const auto m = hxmap::drv::parseMap(bytes, "fuzz.hxm", o);
    if (!m) continue;
    if (m->map.blockCount() + m->skipped_blocks > m->info.blocks) std::abort();
    if (m->keyframes.size() > m->info.keyframes) std::abort();
    if (!skip && (m->skipped_blocks != 0 || m->skipped_keyframes != 0)) std::abort();
  }
  return 0;
}
