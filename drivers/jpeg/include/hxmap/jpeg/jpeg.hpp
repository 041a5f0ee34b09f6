// JPEG images (dataset files, MJPEG camera frames) decoded by libjpeg
// itself. OpenCV's imdecode is not used for JPEG: it hands a damaged scan
// on as a plausible-looking picture, and bytes that do not start like a
// JPEG would be offered to its other decoders (DICOM, TIFF, ...).
#pragma once

#include <cstddef>
#include <cstdint>

#include <opencv2/core.hpp>

#include "hxmap/core/expected.hpp"

namespace hxmap::drv {

/// Starts with SOI (FF D8) and ends with EOI (FF D9), after which up to
/// `padding` bytes are allowed (cameras and some writers pad).
bool isWholeJpeg(const uint8_t* data, size_t bytes, size_t padding);

/// The image as CV_8UC3 R,G,B. An error's text completes a sentence whose
/// subject the caller names ("<file or frame> " + message): "is corrupt:
/// <what libjpeg found>", "has corrupt JPEG data (<first warning>, and N
/// more warnings)" when the scan is damaged, "is WxH pixels, larger than
/// <max_side> on a side". Extraneous bytes before a marker (which many UVC
/// cameras emit) leave every pixel intact and are not an error.
Expected<cv::Mat> decodeJpegRgb(const uint8_t* data, size_t bytes, int max_side = 8192);

}  // namespace hxmap::drv
