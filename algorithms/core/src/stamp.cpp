#include "hxmap/core/stamp.hpp"

#include <cstdio>
#include <cstdlib>

namespace hxmap {

std::optional<int64_t> parseStampNs(std::string_view text) {
  if (text.empty()) return std::nullopt;
  bool negative = false;
  size_t i = 0;
  if (text[0] == '-' || text[0] == '+') {
    negative = text[0] == '-';
    i = 1;
  }
  int64_t seconds = 0;
  size_t int_digits = 0;
  for (; i < text.size() && text[i] != '.'; ++i) {
    const char c = text[i];
    if (c < '0' || c > '9' || int_digits >= 10) return std::nullopt;
    seconds = seconds * 10 + (c - '0');
    ++int_digits;
  }
  int64_t frac_ns = 0;
  size_t frac_digits = 0;
  if (i < text.size()) {
    ++i;  // '.'
    for (; i < text.size(); ++i) {
      const char c = text[i];
      if (c < '0' || c > '9') return std::nullopt;
      if (frac_digits < 9) {
        frac_ns = frac_ns * 10 + (c - '0');
        ++frac_digits;
      }
    }
  }
  if (int_digits == 0 && frac_digits == 0) return std::nullopt;
  // Up to 9e9 s (the year 2255): beyond, seconds * 1e9 leaves int64.
  constexpr int64_t kMaxSeconds = 9'000'000'000LL;
  if (seconds > kMaxSeconds) return std::nullopt;
  for (size_t d = frac_digits; d < 9; ++d) frac_ns *= 10;
  const int64_t ns = seconds * 1000000000LL + frac_ns;
  return negative ? -ns : ns;
}

std::string formatStampS(int64_t stamp_ns, int digits) {
  const bool negative = stamp_ns < 0;
  const int64_t a = negative ? -stamp_ns : stamp_ns;
  int64_t div = 1;
  for (int d = digits; d < 9; ++d) div *= 10;
  const int64_t frac = (a % 1000000000LL) / div;
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%s%lld.%0*lld", negative ? "-" : "", static_cast<long long>(a / 1000000000LL),
                digits, static_cast<long long>(frac));
  return buf;
}

}  // namespace hxmap
