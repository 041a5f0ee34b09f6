// The quality room's sequence for benchmarks: read from a folder written by
// `hxmap synth --scene quality --trajectory inspect --frames 240`, or
// rendered in memory (about 20 s on one core).
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/synthetic.hpp"

namespace hxmap::test {

struct BenchSequence {
  std::vector<RgbdFrame> frames;
  Trajectory ground_truth;
  alg::PinholeCamera camera;
};

/// Every frame of the dataset in `dir` with its camera and ground truth.
/// False (the reason on stderr) when the folder or a frame cannot be read.
inline bool loadDatasetSequence(const std::string& dir, BenchSequence& out) {
  out = BenchSequence{};
  auto ds = drv::Dataset::open(dir);
  if (!ds) {
    std::fprintf(stderr, "%s\n", ds.message().c_str());
    return false;
  }
  out.camera = (*ds)->camera();
  out.ground_truth = (*ds)->groundTruth();
  auto frames = (*ds)->loadAll();
  if (!frames) {
    std::fprintf(stderr, "%s\n", frames.message().c_str());
    return false;
  }
  out.frames = std::move(*frames);
  return true;
}

/// HXMAP_BENCH_SCALE: the quality room's scale (SyntheticScene::scaled;
/// the sequence in a folder must have been written with the same `hxmap
/// synth --scale`), 1 when unset.
inline float benchSceneScale() {
  const char* v = std::getenv("HXMAP_BENCH_SCALE");
  const float s = v ? static_cast<float>(std::atof(v)) : 1.0f;
  return s > 0 ? s : 1.0f;
}

/// The name of a known-bad primitive of the quality room, by what makes it
/// bad: "rod", "board edge", "noisy patch" or "grazing shelf".
inline const char* badRegionName(const drv::Primitive& p) {
  return p.kind == drv::Primitive::Kind::kCapsule ? "rod"
         : p.bad == drv::Primitive::Bad::kEdges   ? "board edge"
         : p.noise_scale > 1                      ? "noisy patch"
                                                  : "grazing shelf";
}

/// The quality room at `scale` (default: benchSceneScale()).
inline drv::SyntheticScene benchQualityRoom(float scale = benchSceneScale()) {
  return drv::SyntheticScene::qualityRoom().scaled(scale);
}

/// `dir` empty or "-": render, at `scale`. False (the reason on stderr) when
/// the folder or one of its frames cannot be read.
inline bool loadOrRenderQualityRoom(const std::string& dir, BenchSequence& out,
                                    const std::string& trajectory = "inspect", float scale = benchSceneScale()) {
  drv::SyntheticParams sp;
  sp.frames = 240;
  sp.trajectory = trajectory;
  sp.scale = scale;
  out = BenchSequence{};
  if (!dir.empty() && dir != "-") return loadDatasetSequence(dir, out);
  std::fprintf(stderr, "rendering the quality room (%d frames, %s trajectory, scale %g) ...\n", sp.frames,
               trajectory.c_str(), static_cast<double>(scale));
  const drv::SyntheticScene scene = benchQualityRoom(scale);
  out.camera = sp.camera;
  out.ground_truth = drv::syntheticTrajectory(sp);
  for (int i = 0; i < sp.frames; ++i) {
    const auto r = drv::renderFrame(scene, out.camera, out.ground_truth[i].T_world_cam, sp, i);
    RgbdFrame f;
    f.stamp_ns = out.ground_truth[i].stamp_ns;
    f.seq = static_cast<uint64_t>(i);
    f.rgb = r.rgb;
    f.depth = r.depth;
    out.frames.push_back(std::move(f));
  }
  return true;
}

}  // namespace hxmap::test
