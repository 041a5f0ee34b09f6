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

/// A noisy synthetic frame at T_world_cam, preprocessed as fusion takes it,
/// posed at T_fuse (the render pose when not given).
inline alg::DepthObservation syntheticObservation(const drv::SyntheticScene& scene, const alg::PinholeCamera& cam,
                                                  const Eigen::Isometry3d& T_world_cam, int index,
                                                  const Eigen::Isometry3d* T_fuse = nullptr) {
  const RgbdFrame f = syntheticFrame(scene, cam, T_world_cam, true, index);
  const auto pre = alg::preprocessFrame({0, 0, f.rgb, f.depth}, cam, alg::PreprocessParams{});
  return {pre.depth_m, pre.rgb, pre.levels[pre.finest].confidence, cam, (T_fuse ? *T_fuse : T_world_cam).cast<float>()};
}

/// The synthetic room at 320x240 along the default trajectory, fused at 2 cm
/// voxels (8 cm truncation): small maps for tests of the map's memory.
struct SmallRoom {
  drv::SyntheticScene scene = drv::SyntheticScene::room();
  alg::PinholeCamera cam{300, 300, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};
  Trajectory traj = drv::syntheticTrajectory(drv::SyntheticParams{});
  static alg::TsdfParams tsdf() {
    alg::TsdfParams p;
    p.voxel_size_m = 0.02;
    p.truncation_m = 0.08;
    return p;
  }
  /// Frame i, noisy, posed at T_fuse (its true pose when not given).
  alg::DepthObservation observe(int i, const Eigen::Isometry3d* T_fuse = nullptr) const {
    return syntheticObservation(scene, cam, traj[static_cast<size_t>(i)].T_world_cam, i, T_fuse);
  }
};

/// RGB (CV_8UC3) to intensity in [0, 1] as the mean of the channels (CV_32F).
inline cv::Mat intensityOf(const cv::Mat& rgb) {
  cv::Mat out(rgb.size(), CV_32F);
  for (int v = 0; v < rgb.rows; ++v) {
    for (int u = 0; u < rgb.cols; ++u) {
      const cv::Vec3b c = rgb.at<cv::Vec3b>(v, u);
      out.at<float>(v, u) = static_cast<float>(c[0] + c[1] + c[2]) / (3.0f * 255.0f);
    }
  }
  return out;
}

}  // namespace hxmap::test
