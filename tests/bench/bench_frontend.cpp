// Backbone benchmark: per-stage medians in ms/frame on a dataset (default:
// the shared TUM fr1/xyz slice at 640x480), on one core, and integration
// alone at 1 cm and 2 cm voxels with the memory it takes per square meter of
// surface. Prints numbers; asserts nothing (timing is not a test).
//
//   bench_frontend [dataset_dir] [repeats] [frontend]
//
// "frontend" stops after the per-stage table. One core throughout: hxmap's
// stages run serially, OpenCV's own threading is switched off, and the
// program restarts itself with OMP_NUM_THREADS=1 (unless set) so that
// Open3D's OpenMP loops run on one thread too.
#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include <unistd.h>

#include <opencv2/core.hpp>

#include "bench_stats.hpp"
#include "hxmap/dataset/dataset.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"

#ifdef HXMAP_HAVE_OPEN3D
#include <open3d/camera/PinholeCameraIntrinsic.h>
#include <open3d/geometry/Image.h>
#include <open3d/geometry/RGBDImage.h>
#include <open3d/pipelines/integration/ScalableTSDFVolume.h>
#endif

using namespace hxmap;

namespace {
using bench::Clock;
using bench::median;
using bench::ms;
}  // namespace

int main(int argc, char** argv) {
  if (std::getenv("OMP_NUM_THREADS") == nullptr) {
    // OpenMP reads the variable when its library loads: set it and restart.
    setenv("OMP_NUM_THREADS", "1", 1);
    execv("/proc/self/exe", argv);
    std::perror("bench_frontend: restarting with OMP_NUM_THREADS=1");
    return 2;
  }
  cv::setNumThreads(0);
  rt::keepHeapBetweenFrames();  // as hxmap's main does
  const bool frontend_only = argc > 3 && std::string(argv[3]) == "frontend";
  const std::string dir = argc > 1 ? argv[1] : std::string(HXMAP_SHARED_DATA) + "/tum/rgbd_dataset_freiburg1_xyz_first40";
  const int repeats = argc > 2 ? std::max(1, std::atoi(argv[2])) : 3;
  auto ds = drv::Dataset::open(dir);
  if (!ds) {
    std::fprintf(stderr, "%s\n", ds.message().c_str());
    return 2;
  }
  const auto& d = **ds;
  std::vector<RgbdFrame> frames;
  for (size_t i = 0; i < d.size(); ++i) {
    auto f = d.load(i);
    if (!f) {
      std::fprintf(stderr, "%s\n", f.message().c_str());
      return 2;
    }
    frames.push_back(std::move(*f));
  }
  std::printf("dataset %s: %zu frames %dx%d, %d repeats, one core\n", dir.c_str(), frames.size(), d.camera().width,
              d.camera().height, repeats);

  // Whole frontend, per stage.
  std::array<std::vector<double>, rt::kStageCount> stage;
  std::vector<double> total, mesh_ms;
  Trajectory poses;
  double ate = -1;
  for (int r = 0; r < repeats; ++r) {
    rt::Frontend fe(d.camera(), rt::FrontendParams{});
    Eigen::Isometry3d T0;
    if (alg::interpolatePose(d.groundTruth(), frames[0].stamp_ns, 200'000'000, T0)) fe.setInitialPose(T0);
    for (const auto& f : frames) {
      const auto res = fe.process(f);
      double sum = 0;
      for (int s = 0; s < rt::kStageCount; ++s) {
        if (fe.trajectory().size() > 1) stage[s].push_back(res.stage_ms[s]);  // the first frame has no tracking
        sum += res.stage_ms[s];
      }
      if (fe.trajectory().size() > 1) total.push_back(sum);
    }
    const auto t0 = Clock::now();
    const auto mesh = alg::extractMesh(fe.map(), alg::MeshParams{});
    mesh_ms.push_back(ms(t0, Clock::now()));
    poses = fe.trajectory();
    if (!d.groundTruth().empty()) ate = alg::computeAte(poses, d.groundTruth()).rmse_m;
  }
  std::printf("\nfrontend at the default 2 cm voxels, ms/frame (median over %zu frames)\n", total.size());
  for (int s = 0; s < rt::kStageCount; ++s) std::printf("  %-12s %8.2f\n", rt::stageName(s), median(stage[s]));
  std::printf("  %-12s %8.2f\n", "total", median(total));
  std::printf("  %-12s %8.2f  (whole map, once per run)\n", "mesh", median(mesh_ms));
  if (ate >= 0) std::printf("  ATE RMSE %.2f cm\n", 100 * ate);
  if (frontend_only) return 0;

  // Integration alone at 1 and 2 cm, along the tracked poses; Open3D's
  // ScalableTSDFVolume on the same frames, poses, voxel size and truncation
  // as the peer, on one thread (OMP_NUM_THREADS=1, see main). DESIGN: the
  // two integrate each frame in turn, so that the machine's load drifting
  // during the run weighs on both alike and the ratio stays honest.
#ifdef HXMAP_HAVE_OPEN3D
  namespace o3d = open3d;
  const auto& c = d.camera();
  const o3d::camera::PinholeCameraIntrinsic intrinsic(c.width, c.height, c.fx, c.fy, c.cx, c.cy);
  std::vector<std::shared_ptr<o3d::geometry::RGBDImage>> images;
  for (const auto& f : frames) {
    o3d::geometry::Image color, depth;
    color.Prepare(c.width, c.height, 3, 1);
    std::memcpy(color.data_.data(), f.rgb.data, color.data_.size());
    depth.Prepare(c.width, c.height, 1, 4);
    std::memcpy(depth.data_.data(), f.depth.data, depth.data_.size());  // float meters
    images.push_back(o3d::geometry::RGBDImage::CreateFromColorAndDepth(color, depth, 1.0,
                                                                       alg::TsdfParams{}.max_integration_depth_m, false));
  }
#endif
  std::printf("\nintegration alone, ms/frame (median) and memory\n");
  for (double voxel : {0.02, 0.01}) {
    alg::TsdfParams tp;
    tp.voxel_size_m = voxel;
    tp.truncation_m = 4 * voxel;
    std::vector<double> t, t3;
    double band_blocks = 0, voxel_updates = 0;
    alg::MapMemory mem;
    double area = 0;
    for (int r = 0; r < repeats; ++r) {
      alg::TsdfMap map(tp);
#ifdef HXMAP_HAVE_OPEN3D
      o3d::pipelines::integration::ScalableTSDFVolume volume(voxel, tp.truncation_m,
                                                             o3d::pipelines::integration::TSDFVolumeColorType::RGB8);
#endif
      for (size_t i = 0; i < frames.size(); ++i) {
        const auto pre = alg::preprocessFrame(frames[i], d.camera(), alg::PreprocessParams{});
        const alg::DepthObservation obs{pre.depth_m, pre.rgb, pre.levels[pre.finest].confidence, d.camera(),
                                        poses[i].T_world_cam.cast<float>()};
        const auto t0 = Clock::now();
        const auto st = alg::integrate(map, obs);
        t.push_back(ms(t0, Clock::now()));
        band_blocks += static_cast<double>(st.blocks_in_band);
        voxel_updates += static_cast<double>(st.voxels_updated);
#ifdef HXMAP_HAVE_OPEN3D
        const Eigen::Matrix4d extrinsic = poses[i].T_world_cam.inverse().matrix();  // world to camera
        const auto t1 = Clock::now();
        volume.Integrate(*images[i], intrinsic, extrinsic);
        t3.push_back(ms(t1, Clock::now()));
#endif
      }
      mem = map.memory();
      area = alg::extractMesh(map, alg::MeshParams{}).surfaceArea();
    }
    std::printf("  hxmap  voxel %.0f cm: %8.2f ms/frame, %zu blocks, %.1f MiB, %.2f m^2 of surface, %.1f MiB/m^2\n",
                voxel * 100, median(t), mem.blocks, mem.bytes / 1048576.0, area, mem.bytes / 1048576.0 / area);
    const double n = static_cast<double>(t.size());
    std::printf("         per frame %.0f blocks in the band, %.0f voxel updates\n", band_blocks / n,
                voxel_updates / n);
    if (!t3.empty()) {
      const double ratio = median(t3) / median(t);
      std::printf("  Open3D voxel %.0f cm: %8.2f ms/frame (ScalableTSDFVolume)  -> hxmap is %.2fx %s\n", voxel * 100,
                  median(t3), ratio >= 1 ? ratio : 1 / ratio, ratio >= 1 ? "faster" : "slower");
    }
  }
  return 0;
}
