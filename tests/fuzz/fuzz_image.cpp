// libFuzzer target: a dataset image file's checks and decoding (PNG and
// JPEG signatures, truncation, type), as color and as 16-bit depth.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "hxmap/dataset/dataset.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  ::setenv("OPENCV_IO_MAX_IMAGE_PIXELS", "67108864", 0);  // as the hxmap program sets it
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  for (bool depth16 : {false, true}) {
    auto image = hxmap::drv::decodeImage(bytes, "fuzz.png", "rgb.txt:1", depth16);
    if (image && image->empty()) std::abort();
  }
  return 0;
}
