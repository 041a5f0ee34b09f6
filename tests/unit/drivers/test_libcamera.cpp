// libcamera without a camera: a clear error, no crash, and the camera
// manager shut down cleanly (the test process exits normally).
#include <gtest/gtest.h>

#include "hxmap/libcamera_drv/libcamera_camera.hpp"

namespace hxmap::drv {
namespace {

TEST(Libcamera, NoCameraOrAnUnknownIdIsAClearError) {
  LibcameraOptions o;
  o.camera_id = "/base/hxmap/no-such-sensor@10";
  auto cam = LibcameraCamera::open(o);
  ASSERT_FALSE(cam);
  // Either nothing is attached, or what is attached is listed.
  const bool none = cam.message().find("libcamera: no camera found") != std::string::npos;
  const bool named = cam.message().find("no camera '/base/hxmap/no-such-sensor@10'") != std::string::npos;
  const bool no_manager = cam.message().find("camera manager did not start") != std::string::npos;
  EXPECT_TRUE(none || named || no_manager) << cam.message();
  // Twice: the manager of the first attempt was stopped and released.
  auto again = LibcameraCamera::open(o);
  EXPECT_FALSE(again);
}

}  // namespace
}  // namespace hxmap::drv
