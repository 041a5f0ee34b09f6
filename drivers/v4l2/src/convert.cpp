#include "hxmap/v4l2/convert.hpp"

#include <linux/videodev2.h>

#include <algorithm>
#include <cstring>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>

#include "hxmap/jpeg/jpeg.hpp"

namespace hxmap::drv {

namespace {

uint8_t clampByte(int v) { return static_cast<uint8_t>(std::clamp(v, 0, 255)); }

Status checkSize(const char* what, size_t bytes, int width, int height, size_t bytes_per_line, size_t bytes_per_pixel) {
  if (width <= 0 || height <= 0) return Error{fmt::format("{}: bad frame size {}x{}", what, width, height)};
  const size_t row = static_cast<size_t>(width) * bytes_per_pixel;
  if (bytes_per_line != 0 && bytes_per_line < row) {
    return Error{fmt::format("{}: row stride {} bytes is less than {} pixels need ({})", what, bytes_per_line, width, row)};
  }
  const size_t stride = bytes_per_line != 0 ? bytes_per_line : row;
  const size_t need = stride * static_cast<size_t>(height - 1) + row;
  if (bytes < need) {
    return Error{fmt::format("{}: buffer holds {} bytes, a {}x{} frame needs {} (truncated frame)", what, bytes, width,
                             height, need)};
  }
  return Status::ok();
}

}  // namespace

const char* formatName(PixelFormat format) {
  switch (format) {
    case PixelFormat::kYuyv: return "YUYV";
    case PixelFormat::kMjpeg: return "MJPEG";
    case PixelFormat::kRgb24: return "RGB24";
    case PixelFormat::kZ16: return "Z16";
  }
  return "?";
}

uint32_t fourccOf(PixelFormat format) {
  switch (format) {
    case PixelFormat::kYuyv: return V4L2_PIX_FMT_YUYV;
    case PixelFormat::kMjpeg: return V4L2_PIX_FMT_MJPEG;
    case PixelFormat::kRgb24: return V4L2_PIX_FMT_RGB24;
    case PixelFormat::kZ16: return V4L2_PIX_FMT_Z16;
  }
  return 0;
}

std::optional<PixelFormat> formatOfFourcc(uint32_t fourcc) {
  for (PixelFormat f : {PixelFormat::kYuyv, PixelFormat::kMjpeg, PixelFormat::kRgb24, PixelFormat::kZ16}) {
    if (fourccOf(f) == fourcc) return f;
  }
  if (fourcc == V4L2_PIX_FMT_JPEG) return PixelFormat::kMjpeg;
  return std::nullopt;
}

bool isDepthFormat(PixelFormat format) { return format == PixelFormat::kZ16; }

std::string fourccText(uint32_t f) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((f >> (8 * i)) & 0xff);
    s += (c >= 32 && c < 127) ? c : '?';
  }
  return s;
}

Expected<cv::Mat> decodeColor(PixelFormat format, const uint8_t* data, size_t bytes, int width, int height,
                              size_t bytes_per_line) {
  switch (format) {
    case PixelFormat::kYuyv: {
      if (width % 2 != 0) return Error{fmt::format("YUYV: odd width {}", width)};
      if (auto s = checkSize("YUYV", bytes, width, height, bytes_per_line, 2); !s) return Error{s.message()};
      const size_t stride = bytes_per_line != 0 ? bytes_per_line : static_cast<size_t>(width) * 2;
      cv::Mat out(height, width, CV_8UC3);
      for (int v = 0; v < height; ++v) {
        const uint8_t* in = data + stride * static_cast<size_t>(v);
        uint8_t* o = out.ptr<uint8_t>(v);
        for (int u = 0; u < width; u += 2, in += 4, o += 6) {
          // BT.601 limited range, integer arithmetic (8-bit fixed point).
          const int y0 = (in[0] - 16) * 298, y1 = (in[2] - 16) * 298;
          const int cb = in[1] - 128, cr = in[3] - 128;
          const int r = 409 * cr + 128, g = -100 * cb - 208 * cr + 128, b = 516 * cb + 128;
          o[0] = clampByte((y0 + r) >> 8);
          o[1] = clampByte((y0 + g) >> 8);
          o[2] = clampByte((y0 + b) >> 8);
          o[3] = clampByte((y1 + r) >> 8);
          o[4] = clampByte((y1 + g) >> 8);
          o[5] = clampByte((y1 + b) >> 8);
        }
      }
      return out;
    }
    case PixelFormat::kRgb24: {
      if (auto s = checkSize("RGB24", bytes, width, height, bytes_per_line, 3); !s) return Error{s.message()};
      const size_t stride = bytes_per_line != 0 ? bytes_per_line : static_cast<size_t>(width) * 3;
      cv::Mat out(height, width, CV_8UC3);
      for (int v = 0; v < height; ++v) std::memcpy(out.ptr<uint8_t>(v), data + stride * static_cast<size_t>(v), static_cast<size_t>(width) * 3);
      return out;
    }
    case PixelFormat::kMjpeg: {
      // A JPEG starts with SOI and (when complete) ends with EOI; some
      // cameras pad after EOI, so look for it near the end.
      if (bytes < 4 || data[0] != 0xFF || data[1] != 0xD8) return Error{fmt::format("MJPEG: {} bytes, no JPEG start marker (corrupt frame)", bytes)};
      if (!isWholeJpeg(data, bytes, 4096))
        return Error{fmt::format("MJPEG: {} bytes, no JPEG end marker (truncated frame)", bytes)};
      auto rgb = decodeJpegRgb(data, bytes, std::max(width, height));
      if (!rgb) return Error{fmt::format("MJPEG: a {}-byte frame {}", bytes, rgb.message())};
      if (rgb->cols != width || rgb->rows != height) {
        return Error{fmt::format("MJPEG: decoded {}x{}, the stream is {}x{}", rgb->cols, rgb->rows, width, height)};
      }
      return rgb;
    }
    case PixelFormat::kZ16:
      return Error{"Z16 is a depth format (use decodeDepth)"};
  }
  return Error{"unknown pixel format"};
}

Expected<cv::Mat> decodeDepth(const uint8_t* data, size_t bytes, int width, int height, size_t bytes_per_line) {
  if (auto s = checkSize("Z16", bytes, width, height, bytes_per_line, 2); !s) return Error{s.message()};
  const size_t stride = bytes_per_line != 0 ? bytes_per_line : static_cast<size_t>(width) * 2;
  cv::Mat out(height, width, CV_16UC1);
  for (int v = 0; v < height; ++v) {
    const uint8_t* in = data + stride * static_cast<size_t>(v);
    uint16_t* o = out.ptr<uint16_t>(v);
    for (int u = 0; u < width; ++u) o[u] = static_cast<uint16_t>(in[2 * u] | (in[2 * u + 1] << 8));
  }
  return out;
}

std::vector<uint8_t> encodeYuyv(const cv::Mat& rgb) {
  std::vector<uint8_t> out(static_cast<size_t>(rgb.cols) * static_cast<size_t>(rgb.rows) * 2);
  size_t k = 0;
  for (int v = 0; v < rgb.rows; ++v) {
    const uint8_t* p = rgb.ptr<uint8_t>(v);
    for (int u = 0; u + 1 < rgb.cols; u += 2, p += 6) {
      auto y = [](const uint8_t* q) { return clampByte(((66 * q[0] + 129 * q[1] + 25 * q[2] + 128) >> 8) + 16); };
      const int r = (p[0] + p[3]) / 2, g = (p[1] + p[4]) / 2, b = (p[2] + p[5]) / 2;
      out[k++] = y(p);
      out[k++] = clampByte(((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128);
      out[k++] = y(p + 3);
      out[k++] = clampByte(((112 * r - 94 * g - 18 * b + 128) >> 8) + 128);
    }
  }
  return out;
}

}  // namespace hxmap::drv
