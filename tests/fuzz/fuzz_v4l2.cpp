// libFuzzer target: the V4L2 frame decoders (YUYV, MJPEG, RGB24, Z16) on
// buffers of any size, with any claimed frame size and row stride. The
// first 6 bytes choose the format, width, height and stride; the rest is
// the buffer the driver would hand over.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "hxmap/v4l2/convert.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 6) return 0;
  using hxmap::drv::PixelFormat;
  const PixelFormat format = static_cast<PixelFormat>(data[0] % 4);
  const int width = 1 + data[1] * 3, height = 1 + data[2] * 2;  // up to 766 x 511
  const size_t stride = (static_cast<size_t>(data[3]) << 8 | data[4]) * (data[5] & 1);
  const uint8_t* buffer = data + 6;
  const size_t bytes = size - 6;
  if (format == PixelFormat::kZ16) {
    auto depth = hxmap::drv::decodeDepth(buffer, bytes, width, height, stride);
    if (depth && (depth->cols != width || depth->rows != height)) std::abort();
  } else {
    auto color = hxmap::drv::decodeColor(format, buffer, bytes, width, height, stride);
    if (color && (color->cols != width || color->rows != height || color->channels() != 3)) std::abort();
  }
  return 0;
}
