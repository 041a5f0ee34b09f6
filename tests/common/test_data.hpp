// Access to the real data slices in ../shared/data for tests.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

namespace hxmap::test {

inline std::string sharedData(const std::string& relative) { return std::string(HXMAP_SHARED_DATA) + "/" + relative; }

inline bool inCi() {
  const char* ci = std::getenv("CI");
  return ci != nullptr && std::string(ci) != "" && std::string(ci) != "false" && std::string(ci) != "0";
}

/// A fresh empty folder under the system temp dir, unique per test.
inline std::string tempDir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const auto dir = std::filesystem::temp_directory_path() /
                   ("hxmap_test_" + std::string(info->test_suite_name()) + "_" + info->name() + "_" + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

}  // namespace hxmap::test

/// In a test body: the shared data folder `rel` must exist; fails in CI,
/// skips elsewhere, with the reason.
#define HXMAP_REQUIRE_SHARED_DATA(rel)                                                                        \
  do {                                                                                                        \
    if (!std::filesystem::exists(::hxmap::test::sharedData(rel))) {                                           \
      if (::hxmap::test::inCi()) {                                                                            \
        FAIL() << "shared data missing in CI: " << ::hxmap::test::sharedData(rel);                            \
      } else {                                                                                                \
        GTEST_SKIP() << "shared data not found at " << ::hxmap::test::sharedData(rel)                         \
                     << " (the real data slices live in ../shared/data beside the repository)";               \
      }                                                                                                       \
    }                                                                                                         \
  } while (0)
