// Helpers for tests on the synthetic room: exact frames and a map built from them.
#pragma once

#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/tsdf/integrate.hpp"

namespace hxmap::test {

inline RgbdFrame syntheticFrame(const drv::SyntheticScene& scene, const alg::PinholeCamera& cam,
                                const Eigen::Isometry3d& T_world_cam, bool noise = false, int index = 0) {
  drv::SyntheticParams p;
  p.noise = noise;
  p.camera = cam;
  const auto r = drv::renderFrame(scene, cam, T_world_cam, p, index);
  RgbdFrame f;
  f.rgb = r.rgb;
  f.depth = r.depth;
  f.seq = static_cast<uint64_t>(index);
  return f;
}

}  // namespace hxmap::test
