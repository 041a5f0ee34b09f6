#include "hxmap/jpeg/jpeg.hpp"

#include <algorithm>
#include <csetjmp>
#include <cstdio>
#include <memory>
#include <string>

#include <fmt/format.h>
#include <jerror.h>
#include <jpeglib.h>

namespace hxmap::drv {
namespace {

// libjpeg reports through callbacks: a fatal error must not return to the
// library (it longjmps back into decodeJpegRgb); warnings are counted.
struct JpegErrors {
  jpeg_error_mgr mgr{};
  std::jmp_buf jump{};
  int damage = 0;
  std::string first;
};

void onFatal(j_common_ptr cinfo) {
  auto* e = reinterpret_cast<JpegErrors*>(cinfo->err);
  char text[JMSG_LENGTH_MAX];
  (*cinfo->err->format_message)(cinfo, text);
  e->first = text;
  std::longjmp(e->jump, 1);
}

void onMessage(j_common_ptr cinfo, int level) {
  if (level >= 0) return;  // trace messages
  if (cinfo->err->msg_code == JWRN_EXTRANEOUS_DATA) return;
  auto* e = reinterpret_cast<JpegErrors*>(cinfo->err);
  if (e->damage++ == 0) {
    char text[JMSG_LENGTH_MAX];
    (*cinfo->err->format_message)(cinfo, text);
    e->first = text;
  }
}

}  // namespace

bool isWholeJpeg(const uint8_t* data, size_t bytes, size_t padding) {
  if (bytes < 4 || data[0] != 0xFF || data[1] != 0xD8) return false;
  const size_t first = bytes - 2 - std::min(padding, bytes - 4);
  for (size_t i = bytes - 2; i + 1 > first; --i) {
    if (data[i] == 0xFF && data[i + 1] == 0xD9) return true;
  }
  return false;
}

Expected<cv::Mat> decodeJpegRgb(const uint8_t* data, size_t bytes, int max_side) {
  jpeg_decompress_struct cinfo{};
  JpegErrors errors;
  cinfo.err = jpeg_std_error(&errors.mgr);
  errors.mgr.error_exit = onFatal;
  errors.mgr.emit_message = onMessage;
  // The image lives on the heap: only the pointee changes after setjmp, so
  // the pointer is still valid when the error handler jumps back.
  const auto rgb = std::make_unique<cv::Mat>();
  if (setjmp(errors.jump) != 0) {
    jpeg_destroy_decompress(&cinfo);
    return Error{fmt::format("is corrupt: {}", errors.first)};
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, data, static_cast<unsigned long>(bytes));
  jpeg_read_header(&cinfo, TRUE);
  if (cinfo.image_width > static_cast<unsigned>(max_side) || cinfo.image_height > static_cast<unsigned>(max_side)) {
    const std::string size = fmt::format("{}x{}", cinfo.image_width, cinfo.image_height);
    jpeg_destroy_decompress(&cinfo);
    return Error{fmt::format("is {} pixels, larger than {} on a side", size, max_side)};
  }
  cinfo.out_color_space = JCS_RGB;
  jpeg_start_decompress(&cinfo);
  rgb->create(static_cast<int>(cinfo.output_height), static_cast<int>(cinfo.output_width), CV_8UC3);
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = rgb->ptr<uint8_t>(static_cast<int>(cinfo.output_scanline));
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  if (errors.damage > 0) {
    return Error{fmt::format("has corrupt JPEG data ({}{})", errors.first,
                             errors.damage > 1 ? fmt::format(", and {} more warnings", errors.damage - 1) : "")};
  }
  return *rgb;
}

}  // namespace hxmap::drv
