// Pose feedback: solve time per window and what the solve recovers, on the
// synthetic room (a map fused from exact poses at 640x480, 2 cm voxels).
// The window holds N keyframes at the image level the runtime uses (level
// 1: 320x240) with about 2k pixels each (base + top + explore), poses
// perturbed as tracking drift would leave them. One core (no parallel-for).
//
// Usage: bench_feedback [window N] [repetitions] [drift scale: 1 as above, 0 = start at the true poses]
//                       [LM iterations: default FeedbackParams::iterations]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/feedback/window.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "synthetic_fixture.hpp"

using namespace hxmap;
using namespace hxmap::alg;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const int n = argc > 1 ? std::atoi(argv[1]) : 8;
  const int reps = argc > 2 ? std::atoi(argv[2]) : 9;
  const double drift_scale = argc > 3 ? std::atof(argv[3]) : 1.0;
  const auto scene = drv::SyntheticScene::room();
  drv::SyntheticParams sp;
  sp.frames = 8 * n + 8;
  sp.noise = true;
  const Trajectory traj = drv::syntheticTrajectory(sp);
  TsdfParams tp;
  TsdfMap map(tp);
  for (size_t i = 0; i < traj.size(); i += 2) {
    const auto r = drv::renderFrame(scene, sp.camera, traj[i].T_world_cam, sp, static_cast<int>(i));
    DepthObservation obs;
    obs.depth_m = r.depth;
    obs.rgb = r.rgb;
    obs.camera = sp.camera;
    obs.T_world_cam = traj[i].T_world_cam.cast<float>();
    integrate(map, obs);
  }
  const PinholeCamera level1 = sp.camera.level(1);
  std::vector<WindowKeyframe> kfs;
  for (int k = 0; k < n; ++k) {
    const size_t i = static_cast<size_t>(4 + 8 * k);
    const auto r = drv::renderFrame(scene, level1, traj[i].T_world_cam, sp, static_cast<int>(i));
    WindowKeyframe kf;
    kf.id = static_cast<uint32_t>(k);
    kf.stamp_ns = static_cast<int64_t>(i) * 33'333'333;
    kf.camera = level1;
    kf.depth = r.depth;
    kf.intensity = test::intensityOf(r.rgb);
    // Drift: an error growing along the window, about 1 cm and 0.5 deg at its end.
    const double a = drift_scale * static_cast<double>(k + 1) / n;
    Vector6d xi;
    xi << 0.004 * a, -0.006 * a, 0.005 * a, 0.008 * a, -0.004 * a, 0.005 * a;
    kf.T_world_cam = traj[i].T_world_cam * expSE3(xi);
    if (k > 0) {
      // Tracking's relative motion (with the same drift) and an ICP-like information.
      kf.odometry_from_previous = kfs.back().T_world_cam.inverse() * kf.T_world_cam;
      kf.odometry_information = Matrix6d::Identity() * 2e4;
      kf.odometry_information.topLeftCorner<3, 3>() *= 4.0;
    }
    kfs.push_back(kf);
  }
  FeedbackParams p;
  p.window = n;
  if (argc > 4) p.iterations = std::max(1, std::atoi(argv[4]));
  std::vector<double> ms, per_iter;
  SolveReport last;
  std::vector<WindowKeyframe> solved;
  for (int r = 0; r < reps; ++r) {
    PoseWindow window(p);
    for (const auto& kf : kfs) window.add(kf, {&map, {}});
    const auto t0 = std::chrono::steady_clock::now();
    last = window.solve({&map, {}});
    const double t = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    ms.push_back(t);
    per_iter.push_back(t / std::max(1, last.iterations));
    solved = window.keyframes();
  }
  // As the runtime solves: the window was solved when its first N-1
  // keyframes were in it, then the newest joins and it is solved again
  // (the N-1 start from their last planes).
  std::vector<double> steady_ms;
  for (int r = 0; r < reps; ++r) {
    PoseWindow window(p);
    for (size_t k = 0; k + 1 < kfs.size(); ++k) window.add(kfs[k], {&map, {}});
    (void)window.solve({&map, {}});
    window.add(kfs.back(), {&map, {}});
    const auto t0 = std::chrono::steady_clock::now();
    (void)window.solve({&map, {}});
    steady_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  {
    PoseWindow window(p);
    for (const auto& kf : kfs) window.add(kf, {&map, {}});
    const auto t0 = std::chrono::steady_clock::now();
    int px = 0;
    for (int r = 0; r < 20; ++r) {
      for (size_t j = 0; j < window.size(); ++j) {
        px += static_cast<int>(window.basePixels(j).size());
        (void)window.linearize(j, window.keyframes()[j].T_world_cam, {&map, {}}, window.basePixels(j));
      }
    }
    const double t = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::printf("  one keyframe's residual factor (raycast, channels, Jacobians): %.3f us per pixel\n", 1000 * t / px);
    // The same cast followed by 10 evaluations on its tangent planes: the
    // planes' share is what a step between casts costs.
    const auto t1 = std::chrono::steady_clock::now();
    int px2 = 0;
    for (int r = 0; r < 20; ++r) {
      for (size_t j = 0; j < window.size(); ++j) {
        px2 += static_cast<int>(window.basePixels(j).size());
        const Eigen::Isometry3d& T_world_kf = window.keyframes()[j].T_world_cam;
        (void)window.linearizeOnPlanes(j, T_world_kf, T_world_kf, {&map, {}}, window.basePixels(j), 10);
      }
    }
    const double t2 = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count();
    std::printf("  on the tangent planes of a cast: %.3f us per pixel\n", 1000 * (t2 - t * px2 / px) / px2 / 10);
  }
  double before_t = 0, after_t = 0, before_r = 0, after_r = 0;
  for (int k = 0; k < n; ++k) {
    const size_t i = static_cast<size_t>(4 + 8 * k);
    const Eigen::Isometry3d eb = traj[i].T_world_cam.inverse() * kfs[static_cast<size_t>(k)].T_world_cam;
    const Eigen::Isometry3d ea = traj[i].T_world_cam.inverse() * solved[static_cast<size_t>(k)].T_world_cam;
    before_t += translationNorm(eb) / n;
    after_t += translationNorm(ea) / n;
    before_r += rotationAngle(eb) * 180 / M_PI / n;
    after_r += rotationAngle(ea) * 180 / M_PI / n;
  }
  const int pixels = last.before.depth_explicit / n;
  std::printf("pose feedback window: N = %d keyframes at %dx%d, about %d depth residuals per keyframe "
              "(base %d + top %d + explore %d pixels), %d iterations (%d accepted), one core\n",
              n, level1.width, level1.height, pixels, p.base_pixels, p.top_pixels, p.explore_pixels, last.iterations,
              last.accepted);
  std::printf("  solve time of a fresh window: median %.2f ms (min %.2f, max %.2f over %d runs); per iteration %.2f ms\n", median(ms),
              *std::min_element(ms.begin(), ms.end()), *std::max_element(ms.begin(), ms.end()), reps,
              median(per_iter));
  std::printf("  solve time when a keyframe joins a window solved before (as the runtime solves): median %.2f ms "
              "(min %.2f, max %.2f)\n",
              median(steady_ms), *std::min_element(steady_ms.begin(), steady_ms.end()),
              *std::max_element(steady_ms.begin(), steady_ms.end()));
  std::printf("  residuals at the end: photometric %d, depth %d (explicit)\n", last.after.photo_explicit,
              last.after.depth_explicit);
  std::printf("  keyframe pose error (mean): %.2f mm, %.3f deg before -> %.2f mm, %.3f deg after\n", 1000 * before_t,
              before_r, 1000 * after_t, after_r);
  return 0;
}
