#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/ply.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/triangle_bvh.hpp"
#include "test_data.hpp"

namespace hxmap::drv {
namespace {

const alg::PinholeCamera kCam{260, 260, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};

TEST(Synthetic, ExactDepthLiesOnTheAnalyticSurface) {
  const SyntheticScene scene = SyntheticScene::room();
  SyntheticParams p;
  p.noise = false;
  p.frames = 40;
  const Trajectory traj = syntheticTrajectory(p);
  for (int i : {0, 20, 39}) {
    const RenderedFrame f = renderFrame(scene, kCam, traj[i].T_world_cam, p, i);
    int checked = 0;
    double worst = 0;
    for (int v = 0; v < kCam.height; v += 3) {
      for (int u = 0; u < kCam.width; u += 3) {
        const float z = f.depth.at<float>(v, u);
        if (z <= 0) continue;
        const Eigen::Vector3d p_world =
            traj[i].T_world_cam * kCam.backproject(static_cast<float>(u), static_cast<float>(v), z).cast<double>();
        worst = std::max(worst, static_cast<double>(std::abs(scene.sdf(p_world.cast<float>()))));
        ++checked;
      }
    }
    EXPECT_GT(checked, 5000);
    // Float ray casting at up to 5 m: within 0.3 mm.
    EXPECT_LT(worst, 3e-4) << "frame " << i << ": |sdf| of back-projected depth (m)";
  }
}

TEST(Synthetic, AScaledSceneSeenFromAScaledTrajectoryIsTheSameImageAtScaledDepth) {
  const SyntheticScene full = SyntheticScene::qualityRoom(), half = full.scaled(0.5f);
  SyntheticParams p;
  p.noise = false;
  p.frames = 90;
  p.trajectory = "inspect";
  const Trajectory a = syntheticTrajectory(p);
  p.scale = 0.5;
  const Trajectory b = syntheticTrajectory(p);
  EXPECT_NEAR(half.sdf(Eigen::Vector3f(0.3f, 0.2f, 0.4f)), 0.5f * full.sdf(Eigen::Vector3f(0.6f, 0.4f, 0.8f)), 1e-6f);
  for (int i : {0, 60}) {  // frame 60: the top of the rise
    EXPECT_NEAR((b[i].T_world_cam.translation() - 0.5 * a[i].T_world_cam.translation()).norm(), 0.0, 1e-9);
    EXPECT_TRUE(b[i].T_world_cam.linear().isApprox(a[i].T_world_cam.linear(), 1e-9));
    const RenderedFrame fa = renderFrame(full, kCam, a[i].T_world_cam, p, i);
    const RenderedFrame fb = renderFrame(half, kCam, b[i].T_world_cam, p, i);
    int both = 0, one = 0, color_off = 0;
    double worst = 0;
    for (int v = 0; v < kCam.height; ++v) {
      for (int u = 0; u < kCam.width; ++u) {
        const float za = fa.depth.at<float>(v, u), zb = fb.depth.at<float>(v, u);
        if ((za > 0) != (zb > 0)) ++one;
        if (!(za > 0 && zb > 0)) continue;
        ++both;
        worst = std::max(worst, static_cast<double>(std::abs(zb - 0.5f * za)));
        const cv::Vec3b ca = fa.rgb.at<cv::Vec3b>(v, u), cb = fb.rgb.at<cv::Vec3b>(v, u);
        color_off += cv::norm(ca, cb, cv::NORM_INF) > 2;
      }
    }
    EXPECT_GT(both, kCam.width * kCam.height / 2) << "frame " << i;
    // Float ray casting: a few pixels on silhouettes may differ.
    EXPECT_LT(one, kCam.width * kCam.height / 500) << "frame " << i << ": pixels with depth in one image only";
    EXPECT_LT(color_off, both / 500) << "frame " << i << ": pixels whose color differs by more than 2";
    EXPECT_LT(worst, 2e-4) << "frame " << i << ": |z_half - z_full / 2| (m)";
  }
}

TEST(Synthetic, TheHandHeldColorCameraIsExposedLaterRowByRowAndBlurred) {
  const SyntheticScene scene = SyntheticScene::room();
  SyntheticParams p;
  p.noise = false;
  p.frames = 60;
  p.trajectory = "fast";
  const int i = 40;
  const Eigen::Isometry3d T_depth = syntheticPose(p, i / p.fps);
  const RenderedFrame ideal = renderFrame(scene, kCam, T_depth, p, i);
  // A delay alone: the whole color image is the ideal one of the pose
  // color_delay_s later, and depth is untouched.
  SyntheticParams delayed = p;
  delayed.color_delay_s = 0.012;
  ASSERT_TRUE(hasColorEffects(delayed));
  const RenderedFrame d = renderFrame(scene, kCam, T_depth, delayed, i);
  const RenderedFrame later = renderFrame(scene, kCam, syntheticPose(p, i / p.fps + 0.012), p, i);
  EXPECT_EQ(cv::norm(d.rgb, later.rgb, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(d.depth, ideal.depth, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(d.rgb, ideal.rgb, cv::NORM_L1), 0.0);
  // A rolling shutter: the middle row is exposed at the stamp, the top row
  // half the readout earlier.
  SyntheticParams rolling = p;
  rolling.rolling_shutter_s = 0.03;
  const RenderedFrame r = renderFrame(scene, kCam, T_depth, rolling, i);
  const RenderedFrame early = renderFrame(scene, kCam, syntheticPose(p, i / p.fps - 0.015 * (1 - 1.0 / kCam.height)), p, i);
  EXPECT_EQ(cv::norm(r.rgb.row(0), early.rgb.row(0), cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(r.rgb.row(0), ideal.rgb.row(0), cv::NORM_L1), 0.0);
  // Motion blur: less intensity gradient than the sharp image.
  SyntheticParams blurred = p;
  blurred.exposure_s = 0.03;
  const RenderedFrame b = renderFrame(scene, kCam, T_depth, blurred, i);
  auto gradientEnergy = [](const cv::Mat& rgb) {
    cv::Mat gray, gx;
    cv::cvtColor(rgb, gray, cv::COLOR_RGB2GRAY);
    cv::Sobel(gray, gx, CV_32F, 1, 0);
    return cv::norm(gx, cv::NORM_L1);
  };
  EXPECT_LT(gradientEnergy(b.rgb), 0.9 * gradientEnergy(ideal.rgb));
}

TEST(Synthetic, TheStreetIsRenderedFromTheNearbyPrimitivesAsFromAllAndItsWalkStaysInTheStreet) {
  const SyntheticScene street = SyntheticScene::street();
  ASSERT_GT(street.primitives().size(), 150u);
  SyntheticParams p;
  p.trajectory = "street";
  p.frames = 10000;
  const Trajectory walk = syntheticTrajectory(p);
  double path_m = 0;
  for (size_t i = 0; i < walk.size(); ++i) {
    const Eigen::Vector3d eye = walk[i].T_world_cam.translation();
    ASSERT_LT(std::abs(eye.y()), 1.0) << "frame " << i << ": in the middle of the street";
    ASSERT_GT(street.sdf(eye.cast<float>()), 0.4f) << "frame " << i << ": in free space";
    if (i > 0) path_m += (eye - walk[i - 1].T_world_cam.translation()).norm();
  }
  EXPECT_GT(path_m, 280.0) << "10,000 frames: end to end, back, and a fifth of the way again";
  const TrajectorySpeeds speeds = trajectorySpeeds(walk);
  EXPECT_LT(speeds.max_linear_mps, 2.0);
  EXPECT_GT(speeds.max_angular_dps, 20.0);
  // With the sensor model each frame is rendered from the primitives within
  // its range (near()): the true depth and the color it shows there are
  // those of the whole scene rendered without culling.
  SyntheticParams exact = p;
  exact.noise = false;
  for (int i : {0, 2500, 4321, 7200}) {
    const Eigen::Isometry3d& T = walk[static_cast<size_t>(i)].T_world_cam;
    const SyntheticScene near = street.near(T.translation().cast<float>(), 7.0f);
    EXPECT_LT(near.primitives().size(), street.primitives().size() / 3) << "frame " << i;
    const RenderedFrame culled = renderFrame(street, kCam, T, p, i);
    const RenderedFrame all = renderFrame(street, kCam, T, exact, i);
    int compared = 0, differ = 0;
    for (int v = 0; v < kCam.height; ++v) {
      for (int u = 0; u < kCam.width; ++u) {
        const float z = all.depth_true.at<float>(v, u);
        if (z <= 0 || z > p.max_depth_m) continue;
        ++compared;
        const cv::Vec3b a = all.rgb.at<cv::Vec3b>(v, u), b = culled.rgb.at<cv::Vec3b>(v, u);
        const bool same_color = std::abs(a[0] - b[0]) <= 10 && std::abs(a[1] - b[1]) <= 10 &&
                                std::abs(a[2] - b[2]) <= 10;  // color noise of sigma 2
        differ += culled.depth_true.at<float>(v, u) != z || !same_color;
      }
    }
    EXPECT_GT(compared, kCam.width * kCam.height / 8) << "frame " << i << " sees the street within range";
    EXPECT_EQ(differ, 0) << "frame " << i;
  }
}

TEST(Synthetic, GroundTruthMeshMatchesTheSdf) {
  const SyntheticScene scene = SyntheticScene::room();
  const alg::TriangleMesh mesh = scene.mesh();
  // Mesh vertices lie on the surface, or inside another solid where
  // primitives touch (a leg under the table top): never in free space.
  size_t on_surface = 0;
  for (const auto& v : mesh.vertices) {
    const float d = scene.sdf(v);
    EXPECT_LT(d, 1e-4f);
    on_surface += std::abs(d) < 1e-4f;
  }
  EXPECT_GT(on_surface, mesh.vertices.size() * 3 / 4);  // the rest: caps buried in the floor and table
  // Surface points from rendering are within 1 mm of the mesh.
  const alg::TriangleBvh bvh(mesh);
  SyntheticParams p;
  p.noise = false;
  const auto traj = syntheticTrajectory(p);
  const RenderedFrame f = renderFrame(scene, kCam, traj[10].T_world_cam, p, 10);
  double worst_mesh = 0;
  for (int v = 0; v < kCam.height; v += 7) {
    for (int u = 0; u < kCam.width; u += 7) {
      const float z = f.depth.at<float>(v, u);
      if (z <= 0) continue;
      const Eigen::Vector3f pw = (traj[10].T_world_cam.cast<float>() * kCam.backproject(u, v, z));
      worst_mesh = std::max(worst_mesh, static_cast<double>(bvh.distance(pw)));
    }
  }
  EXPECT_LT(worst_mesh, 1e-3);
}

TEST(Synthetic, NoiseModelIsDeterministicAndKinectLike) {
  const SyntheticScene scene = SyntheticScene::room();
  SyntheticParams p;
  p.seed = 7;
  const auto traj = syntheticTrajectory(p);
  const RenderedFrame a = renderFrame(scene, kCam, traj[5].T_world_cam, p, 5);
  const RenderedFrame b = renderFrame(scene, kCam, traj[5].T_world_cam, p, 5);
  EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.rgb, b.rgb, cv::NORM_INF), 0.0);
  // Noise grows with z^2: compare error spread near 1.5 m and near 3 m.
  std::vector<double> near, far;
  int invalid = 0, valid_true = 0;
  for (int v = 0; v < kCam.height; ++v) {
    for (int u = 0; u < kCam.width; ++u) {
      const float zt = a.depth_true.at<float>(v, u), zn = a.depth.at<float>(v, u);
      if (zt <= 0) continue;
      ++valid_true;
      if (zn <= 0) {
        ++invalid;
        continue;
      }
      if (zt > 1.3f && zt < 1.7f) near.push_back(zn - zt);
      if (zt > 2.8f && zt < 3.2f) far.push_back(zn - zt);
    }
  }
  auto rms = [](const std::vector<double>& e) {
    double s = 0;
    for (double x : e) s += x * x;
    return std::sqrt(s / std::max<size_t>(1, e.size()));
  };
  ASSERT_GT(near.size(), 100u);
  ASSERT_GT(far.size(), 100u);
  EXPECT_GT(rms(far), 2.0 * rms(near));
  EXPECT_LT(rms(near), 0.01);
  EXPECT_GT(invalid, 0) << "edges and grazing angles must drop pixels";
  EXPECT_LT(invalid, valid_true / 5);
}

// Parameters of a short sequence of the room at kCam.
SyntheticParams shortSequence(int frames) {
  SyntheticParams p;
  p.frames = frames;
  p.camera = kCam;
  return p;
}

TEST(Synthetic, WritesTumLayoutThatReadsBack) {
  const std::string dir = test::tempDir("seq");
  const SyntheticParams p = shortSequence(4);
  ASSERT_TRUE(writeSyntheticSequence(dir, SyntheticScene::room(), p));
  for (const char* f : {"rgb.txt", "depth.txt", "groundtruth.txt", "calibration.yaml", "gt_mesh.ply"}) {
    EXPECT_TRUE(std::filesystem::exists(std::filesystem::path(dir) / f)) << f;
  }
  auto d = Dataset::open(dir);
  ASSERT_TRUE(d) << d.message();
  EXPECT_EQ((*d)->size(), 4u);
  EXPECT_EQ((*d)->camera().width, 320);
  ASSERT_EQ((*d)->groundTruth().size(), 4u);
  const auto traj = syntheticTrajectory(p);
  EXPECT_LT(((*d)->groundTruth()[3].T_world_cam.translation() - traj[3].T_world_cam.translation()).norm(), 1e-5);
  auto f = (*d)->load(2);
  ASSERT_TRUE(f) << f.message();
  const RenderedFrame r = renderFrame(SyntheticScene::room(), kCam, traj[2].T_world_cam, p, 2);
  // uint16 at 5000 per meter: within 0.1 mm of the rendered depth.
  EXPECT_LT(cv::norm(f->depth, r.depth, cv::NORM_INF), 1.01e-4);
  auto mesh = readPly(dir + "/gt_mesh.ply");
  ASSERT_TRUE(mesh) << mesh.message();
  EXPECT_EQ(mesh->triangles.size(), SyntheticScene::room().mesh().triangles.size());
  // The sensor's grazing cut-off travels with the sequence (mesh evaluation
  // counts surface seen only beyond it as never measured).
  EXPECT_DOUBLE_EQ((*d)->sensorGrazingCos(), p.grazing_cos);
}

TEST(Synthetic, ABadSensorGrazingCosineIsAnErrorNamingTheFile) {
  const std::string dir = test::tempDir("seq_cos");
  ASSERT_TRUE(writeSyntheticSequence(dir, SyntheticScene::room(), shortSequence(2)));
  const std::string calib = dir + "/calibration.yaml";
  std::string text;
  {
    std::ifstream in(calib);
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const std::string key = "sensor_grazing_cos: 0.1\n";
  const auto at = text.find(key);
  ASSERT_NE(at, std::string::npos) << text;
  text.replace(at, key.size(), "sensor_grazing_cos: 1.5\n");
  std::ofstream(calib) << text;
  auto d = Dataset::open(dir);
  ASSERT_FALSE(d);
  EXPECT_NE(d.message().find("calibration.yaml"), std::string::npos) << d.message();
  EXPECT_NE(d.message().find("sensor_grazing_cos"), std::string::npos) << d.message();
}

}  // namespace
}  // namespace hxmap::drv
