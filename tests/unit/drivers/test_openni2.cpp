// OpenNI2 without a camera: a missing recording, a file that is not a
// recording and an absent device are clear errors naming what is at fault.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>

#include "hxmap/openni2/openni2.hpp"

namespace hxmap::drv {
namespace {

TEST(OpenNi2, MissingRecordingIsAnErrorNamingTheFile) {
  OpenNi2Options o;
  o.uri = "/nonexistent/hxmap_capture.oni";
  auto cam = OpenNi2Camera::open(o);
  ASSERT_FALSE(cam);
  EXPECT_NE(cam.message().find("/nonexistent/hxmap_capture.oni: no such recording"), std::string::npos) << cam.message();
}

TEST(OpenNi2, CorruptRecordingIsAnErrorNamingTheFile) {
  const std::string path = ::testing::TempDir() + "/not_a_recording.oni";
  std::ofstream(path) << "this is not an ONI recording\n";
  OpenNi2Options o;
  o.uri = path;
  auto cam = OpenNi2Camera::open(o);
  ASSERT_FALSE(cam);
  EXPECT_NE(cam.message().find(path), std::string::npos) << cam.message();
  std::remove(path.c_str());
}

TEST(OpenNi2, NoDeviceIsAClearError) {
  auto cam = OpenNi2Camera::open(OpenNi2Options{});
  if (cam) GTEST_SKIP() << "an OpenNI2 device is attached: " << (*cam)->name();
  // Either no device is attached (what to check is named) or the OpenNI2
  // runtime itself cannot start (its own reason is given).
  const std::string& m = cam.message();
  const bool no_device = m.rfind("OpenNI2: no device found", 0) == 0 && m.find("plugged in") != std::string::npos;
  const bool no_runtime = m.rfind("OpenNI2: initialization failed: ", 0) == 0 && m.size() > 32;
  EXPECT_TRUE(no_device || no_runtime) << m;
}

}  // namespace
}  // namespace hxmap::drv
