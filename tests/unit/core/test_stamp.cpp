#include <gtest/gtest.h>

#include "hxmap/core/stamp.hpp"

namespace hxmap {
namespace {

TEST(Stamp, ParsesTumSecondsExactly) {
  EXPECT_EQ(parseStampNs("1305031102.175304").value(), 1305031102175304000LL);
  EXPECT_EQ(parseStampNs("1.5").value(), 1500000000LL);
  EXPECT_EQ(parseStampNs("-0.25").value(), -250000000LL);
  EXPECT_EQ(parseStampNs("7").value(), 7000000000LL);
  EXPECT_EQ(parseStampNs("0.1234567891234").value(), 123456789LL);  // beyond ns truncated
}

TEST(Stamp, RejectsGarbage) {
  for (const char* bad : {"", "abc", "1.2.3", "1e9", ".", "12345678901234.0", "1,5"}) {
    EXPECT_FALSE(parseStampNs(bad).has_value()) << bad;
  }
}

TEST(Stamp, RejectsStampsBeyondTheInt64Range) {
  // Found by the fuzzer: 11 digits of seconds overflowed seconds * 1e9.
  EXPECT_FALSE(parseStampNs("13050310989"));
  EXPECT_FALSE(parseStampNs("9999999999.5"));
  EXPECT_FALSE(parseStampNs("-9000000001"));
  EXPECT_EQ(parseStampNs("9000000000.000000001").value(), 9'000'000'000'000'000'001LL);
  EXPECT_EQ(parseStampNs("-9000000000").value(), -9'000'000'000'000'000'000LL);
}

TEST(Stamp, FormatsRoundTrip) {
  EXPECT_EQ(formatStampS(1305031102175304000LL), "1305031102.175304");
  EXPECT_EQ(parseStampNs(formatStampS(1000033333000LL)).value(), 1000033333000LL);
}

}  // namespace
}  // namespace hxmap
