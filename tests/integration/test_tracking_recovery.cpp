// Tracking through a blackout: the synthetic orbit with 1.5 s of no depth
// and black color while the camera moves about 0.6 m. The frontend must
// stay lost while there is nothing to track, relocalize within 10 frames of
// the depth coming back, fuse nothing while lost, and keep the whole
// trajectory (lost frames interpolated once found) within 2 cm ATE.
#include <gtest/gtest.h>

#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::rt {
namespace {

TEST(TrackingRecovery, ABlackoutIsRelocalizedAfterTheDepthReturns) {
  const alg::PinholeCamera cam{525.0, 525.0, 319.5, 239.5, 640, 480, {0, 0, 0, 0, 0}};
  drv::SyntheticParams sp;
  sp.frames = 150;
  sp.camera = cam;
  const Trajectory truth = drv::syntheticTrajectory(sp);
  const drv::SyntheticScene scene = drv::SyntheticScene::room();
  const int dark_first = 60, dark_last = 104;  // 2.0 s to 3.5 s
  FrontendParams p;
  p.refine.enabled = false;
  Frontend fe(cam, p);
  fe.setInitialPose(truth.front().T_world_cam);
  int back_at = -1;
  size_t blocks_before_dark = 0, blocks_end_of_dark = 0;
  for (int i = 0; i < sp.frames; ++i) {
    RgbdFrame f = test::syntheticFrame(scene, cam, truth[static_cast<size_t>(i)].T_world_cam, true, i);
    f.stamp_ns = truth[static_cast<size_t>(i)].stamp_ns;
    const bool dark = i >= dark_first && i <= dark_last;
    if (dark) {
      f.depth.setTo(0.0f);
      f.rgb.setTo(cv::Scalar(0, 0, 0));
    }
    const FrameResult r = fe.process(f);
    if (dark) {
      EXPECT_FALSE(r.tracked) << "frame " << i;
      EXPECT_FALSE(r.integrated) << "frame " << i;
    }
    if (i == dark_first - 1) blocks_before_dark = fe.map().blockCount();
    if (i == dark_last) blocks_end_of_dark = fe.map().blockCount();
    if (i > dark_last && back_at < 0 && r.state == alg::TrackingState::kTracked) back_at = i;
  }
  EXPECT_EQ(blocks_end_of_dark, blocks_before_dark) << "nothing fused while lost";
  ASSERT_GE(back_at, 0) << "tracking never came back";
  EXPECT_LE(back_at - dark_last, 10) << "frames after the depth returned";
  EXPECT_GE(fe.trackingCounts().relocalized, 1u);
  const alg::AteResult ate = alg::computeAte(fe.trajectory(), truth);
  std::printf("blackout: back %d frames after the depth, %zu lost, ATE %.2f cm\n", back_at - dark_last, fe.lostFrames(),
              100 * ate.rmse_m);
  EXPECT_LT(ate.rmse_m, 0.02);
}

}  // namespace
}  // namespace hxmap::rt
