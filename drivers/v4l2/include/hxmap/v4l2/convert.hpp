// Pixel formats of UVC color and depth cameras, decoded from a captured
// buffer into the images the pipeline takes. Every size is checked against
// the buffer's byte count first: a short (truncated) buffer or a corrupt
// JPEG is an Error, never a read past the end.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>
#include <string>

#include <opencv2/core.hpp>

#include "hxmap/core/expected.hpp"

namespace hxmap::drv {

enum class PixelFormat { kYuyv, kMjpeg, kRgb24, kZ16 };

const char* formatName(PixelFormat format);
/// The V4L2 fourcc of a format, and back (nullopt for formats hxmap does not read).
uint32_t fourccOf(PixelFormat format);
std::optional<PixelFormat> formatOfFourcc(uint32_t fourcc);
bool isDepthFormat(PixelFormat format);
/// "YUYV, MJPG, RGB3, Z16 " style names for messages.
std::string fourccText(uint32_t fourcc);

/// Color formats to CV_8UC3 R,G,B. `bytes_per_line` is the row stride
/// (0 = packed); `bytes` what the buffer holds.
Expected<cv::Mat> decodeColor(PixelFormat format, const uint8_t* data, size_t bytes, int width, int height,
                              size_t bytes_per_line = 0);
/// Z16 (little-endian 16-bit depth units) to CV_16UC1.
Expected<cv::Mat> decodeDepth(const uint8_t* data, size_t bytes, int width, int height, size_t bytes_per_line = 0);

/// The YUYV encoding of an RGB image (BT.601 limited range, what UVC
/// cameras send), for tests and for replaying captured RGB as a camera.
std::vector<uint8_t> encodeYuyv(const cv::Mat& rgb);

}  // namespace hxmap::drv
