// Timestamps are int64 nanoseconds everywhere. Dataset files write seconds
// with a decimal fraction; parsing through double loses precision for Unix
// times (16+ significant digits), so these helpers parse the digits exactly.
#pragma once

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace hxmap {

/// Parses "1305031102.175304" (seconds) into nanoseconds. Returns nullopt for
/// anything that is not [-]digits[.digits] with at most 9 fraction digits used
/// (further digits are truncated).
std::optional<int64_t> parseStampNs(std::string_view text);

/// Milliseconds (a duration) to nanoseconds, rounded to the nearest.
inline int64_t msToNs(double ms) { return static_cast<int64_t>(std::llround(ms * 1e6)); }

/// Formats nanoseconds as seconds with 6 fraction digits ("1305031102.175304").
std::string formatStampS(int64_t stamp_ns, int digits = 6);

}  // namespace hxmap
