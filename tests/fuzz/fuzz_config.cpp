// libFuzzer target: the YAML configuration (every section, rig: included).
#include <cstddef>
#include <cstdint>
#include <string>

#include "hxmap/config/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto config = hxmap::rt::loadConfigFromString(text, "fuzz.yaml");
  if (config) (void)hxmap::rt::dumpConfig(*config);
  return 0;
}
