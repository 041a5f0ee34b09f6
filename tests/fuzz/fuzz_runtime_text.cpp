// libFuzzer target: the runtime's text inputs: a --camera spec, and a
// timing trace (Chrome JSON) with the replay built from it.
#include <cstddef>
#include <cstdint>
#include <string>

#include "hxmap/camera/camera_source.hpp"
#include "hxmap/scheduler/trace.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  (void)hxmap::rt::parseCameraSpec(text);
  auto events = hxmap::rt::parseTrace(text, "fuzz.json");
  if (events) {
    (void)hxmap::rt::replayFramesFromTrace(*events);
    (void)hxmap::rt::replayFramesFromTrace(*events, 30.0);
  }
  return 0;
}
