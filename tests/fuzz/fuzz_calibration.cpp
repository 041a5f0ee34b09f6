// libFuzzer target: a dataset's camera files (calibration.yaml, Replica's
// cam_params.json). Any input gives a value or an error, never a crash; a
// value is always a camera hxmap can use.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "hxmap/dataset/dataset.hpp"

namespace {
void checkUsable(const hxmap::Expected<hxmap::drv::Calibration>& c) {
  if (!c) return;
  const auto& k = c->camera;
  const bool ok = k.width >= 1 && k.width <= 8192 && k.height >= 1 && k.height <= 8192 && k.fx > 0 && k.fy > 0 &&
                  std::isfinite(k.fx) && std::isfinite(k.fy) && k.cx >= 0 && k.cx < k.width && k.cy >= 0 &&
                  k.cy < k.height && c->depth_scale > 0 && std::isfinite(c->depth_scale);
  if (!ok) std::abort();  // accepted a camera it must refuse
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  checkUsable(hxmap::drv::parseCalibrationYaml(text, "calibration.yaml"));
  checkUsable(hxmap::drv::parseReplicaCamParams(text, "cam_params.json"));
  return 0;
}
