// Pose feedback: the analytic Jacobians of every residual channel against
// finite differences, the marginalization against a dense elimination, and
// the window solve recovering perturbed keyframe poses on the synthetic room
// (a map fused from exact poses).
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cstdio>

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/feedback/window.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "synthetic_fixture.hpp"

namespace hxmap::alg {
namespace {

constexpr double kDeg = M_PI / 180.0;

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}
double quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[static_cast<size_t>(q * static_cast<double>(v.size() - 1))];
}

Vector6d unit(int k) {
  Vector6d e = Vector6d::Zero();
  e(k) = 1;
  return e;
}

// The synthetic room fused from exact poses (no noise), and keyframes
// rendered at ground-truth poses.
class FeedbackTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new drv::SyntheticScene(drv::SyntheticScene::room());
    drv::SyntheticParams sp;
    sp.frames = 40;
    sp.noise = false;
    sp.camera = cam_;
    traj_ = new Trajectory(drv::syntheticTrajectory(sp));
    TsdfParams tp;
    tp.voxel_size_m = 0.02;
    tp.truncation_m = 0.08;
    map_ = new TsdfMap(tp);
    for (size_t i = 0; i < traj_->size(); i += 2) {
      const auto r = drv::renderFrame(*scene_, cam_, (*traj_)[i].T_world_cam, sp, static_cast<int>(i));
      DepthObservation obs;
      obs.depth_m = r.depth;
      obs.rgb = r.rgb;
      obs.camera = cam_;
      obs.T_world_cam = (*traj_)[i].T_world_cam.cast<float>();
      integrate(*map_, obs);
    }
  }
  static void TearDownTestSuite() {
    delete map_;
    delete traj_;
    delete scene_;
  }

  static WindowKeyframe keyframe(size_t i) {
    drv::SyntheticParams sp;
    sp.noise = false;
    sp.camera = cam_;
    const auto r = drv::renderFrame(*scene_, cam_, (*traj_)[i].T_world_cam, sp, static_cast<int>(i));
    WindowKeyframe kf;
    kf.id = static_cast<uint32_t>(i);
    kf.stamp_ns = static_cast<int64_t>(i) * 33'333'333;
    kf.T_world_cam = (*traj_)[i].T_world_cam;
    kf.camera = cam_;
    kf.depth = r.depth;
    kf.intensity = test::intensityOf(r.rgb);
    return kf;
  }
  FeedbackMaps maps() const { return {map_, {}}; }

  static inline const PinholeCamera cam_{200, 200, 119.5, 89.5, 240, 180, {0, 0, 0, 0, 0}};
  static inline drv::SyntheticScene* scene_ = nullptr;
  static inline Trajectory* traj_ = nullptr;
  static inline TsdfMap* map_ = nullptr;
};

TEST_F(FeedbackTest, DepthJacobianMatchesFiniteDifferencesOfTheRaycast) {
  const WindowKeyframe kf = keyframe(10);
  BlockCache cache(*map_);
  std::vector<double> rel;
  for (int v = 10; v < cam_.height - 10; v += 9) {
    for (int u = 10; u < cam_.width - 10; u += 11) {
      const double D = kf.depth.at<float>(v, u);
      SurfaceHit hit;
      if (!castExplicit(cache, *map_, cam_, kf.T_world_cam, u, v, D, 70, hit)) continue;
      Vector6d J;
      depthResidual(cam_, kf.T_world_cam, u, v, D, hit, J);
      Vector6d J_fd;
      bool ok = true;
      const double h = 1e-4;
      for (int k = 0; k < 6 && ok; ++k) {
        SurfaceHit hp, hm;
        ok = castExplicit(cache, *map_, cam_, kf.T_world_cam * expSE3(h * unit(k)), u, v, hit.z, 89, hp) &&
             castExplicit(cache, *map_, cam_, kf.T_world_cam * expSE3(-h * unit(k)), u, v, hit.z, 89, hm);
        J_fd(k) = ((D - hp.z) - (D - hm.z)) / (2 * h);
      }
      if (!ok) continue;
      rel.push_back((J - J_fd).norm() / std::max(J.norm(), 1e-3));
    }
  }
  ASSERT_GT(rel.size(), 150u);
  // The trilinear field is smooth inside cells and planar patches are exact;
  // kinks at cell faces and curved surfaces leave a few pixels off.
  EXPECT_LT(median(rel), 0.01) << "median relative error";
  EXPECT_LT(quantile(rel, 0.9), 0.05) << "90th percentile";
}

TEST_F(FeedbackTest, PhotometricJacobianMatchesFiniteDifferencesOfTheReprojection) {
  // A smooth analytic image, so that its gradient is exact: the test is of
  // the projection and pose chain.
  auto image = [](double u, double v) { return 0.5 + 0.2 * std::sin(0.11 * u) * std::cos(0.07 * v); };
  auto grad = [](double u, double v) {
    return Eigen::Vector2d(0.2 * 0.11 * std::cos(0.11 * u) * std::cos(0.07 * v),
                           -0.2 * 0.07 * std::sin(0.11 * u) * std::sin(0.07 * v));
  };
  const WindowKeyframe kf = keyframe(14);
  BlockCache cache(*map_);
  int checked = 0;
  for (int v = 12; v < cam_.height - 12; v += 15) {
    for (int u = 12; u < cam_.width - 12; u += 17) {
      SurfaceHit hit;
      if (!castExplicit(cache, *map_, cam_, kf.T_world_cam, u, v, kf.depth.at<float>(v, u), 70, hit)) continue;
      const Eigen::Vector2d g = grad(u, v);
      Vector6d J;
      const double r0 = photoResidual(cam_, kf.T_world_cam, u, v, image(u, v), g.x(), g.y(), hit, J);
      EXPECT_NEAR(r0, image(u, v) - hit.intensity, 1e-12);
      Vector6d J_fd;
      const double h = 1e-6;
      for (int k = 0; k < 6; ++k) {
        auto r = [&](double s) {
          const Eigen::Vector3d x = (kf.T_world_cam * expSE3(s * unit(k))).inverse() * hit.point_world;
          return image(cam_.fx * x.x() / x.z() + cam_.cx, cam_.fy * x.y() / x.z() + cam_.cy) - hit.intensity;
        };
        J_fd(k) = (r(h) - r(-h)) / (2 * h);
      }
      EXPECT_LT((J - J_fd).norm(), 1e-4 * std::max(1.0, J.norm())) << "pixel " << u << "," << v << "\n"
                                                                     << J.transpose() << "\n"
                                                                     << J_fd.transpose();
      ++checked;
    }
  }
  EXPECT_GT(checked, 50);
}

// A plane z = z0 (world) over a box, as an implicit field would answer.
class PlaneSurface : public ImplicitSurface {
 public:
  PlaneSurface(const Eigen::AlignedBox3f& box, float z0) : box_(box), z0_(z0) {}
  const Eigen::AlignedBox3f& box() const override { return box_; }
  bool intersect(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float, float& t, Eigen::Vector3f& n,
                 Eigen::Vector3f& rgb) const override {
    if (std::abs(d.z()) < 1e-6f) return false;
    t = (z0_ - o.z()) / d.z();
    if (t <= 0) return false;
    n = Eigen::Vector3f(0, 0, 1);
    const Eigen::Vector3f p = o + t * d;
    rgb = Eigen::Vector3f::Constant(128 + 100 * std::sin(8 * p.x()));
    return true;
  }

 private:
  Eigen::AlignedBox3f box_;
  float z0_;
};

TEST(FeedbackResiduals, ImplicitDepthJacobianComesFromTheFieldsGradient) {
  const PinholeCamera cam{200, 200, 119.5, 89.5, 240, 180, {0, 0, 0, 0, 0}};
  const PlaneSurface plane(Eigen::AlignedBox3f(Eigen::Vector3f(-5, -5, -1), Eigen::Vector3f(5, 5, 1)), 0.0f);
  // A camera 1.5 m above the floor looking down and forward.
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  T_world_cam.linear() =
      (Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  T_world_cam.translation() = Eigen::Vector3d(0.1, -0.2, 1.5);
  int checked = 0;
  for (int v = 5; v < 180; v += 20) {
    for (int u = 5; u < 240; u += 20) {
      SurfaceHit hit;
      ASSERT_TRUE(castImplicit(plane, cam, T_world_cam, u, v, 2.0, 89, hit));
      Vector6d J;
      depthResidual(cam, T_world_cam, u, v, 2.0, hit, J);
      Vector6d J_fd;
      const double h = 1e-3;  // the field answers in float: a step well above its rounding
      for (int k = 0; k < 6; ++k) {
        SurfaceHit hp, hm;
        ASSERT_TRUE(castImplicit(plane, cam, T_world_cam * expSE3(h * unit(k)), u, v, 2.0, 89, hp));
        ASSERT_TRUE(castImplicit(plane, cam, T_world_cam * expSE3(-h * unit(k)), u, v, 2.0, 89, hm));
        J_fd(k) = (hm.z - hp.z) / (2 * h);
      }
      EXPECT_LT((J - J_fd).norm(), 2e-3 * std::max(1.0, J.norm())) << J.transpose() << "\n" << J_fd.transpose();
      ++checked;
    }
  }
  EXPECT_GT(checked, 80);
}

TEST(FeedbackResiduals, RelativePoseJacobiansMatchFiniteDifferences) {
  const Eigen::Isometry3d Ta = expSE3((Vector6d() << 0.1, -0.2, 0.3, 1.0, 0.5, -0.2).finished());
  const Eigen::Isometry3d Z = expSE3((Vector6d() << 0.02, 0.05, -0.01, 0.1, 0.0, 0.05).finished());
  // Tb near Ta * Z: the residual is small, as between consecutive keyframes.
  const Eigen::Isometry3d Tb = Ta * Z * expSE3((Vector6d() << 1e-3, -2e-3, 5e-4, 2e-3, 1e-3, -1e-3).finished());
  Matrix6d Ja, Jb;
  const Vector6d e = relativePoseResidual(Z, Ta, Tb, &Ja, &Jb);
  EXPECT_LT(e.norm(), 0.01);
  const double h = 1e-6;
  Matrix6d Ja_fd, Jb_fd;
  for (int k = 0; k < 6; ++k) {
    Ja_fd.col(k) = (relativePoseResidual(Z, Ta * expSE3(h * unit(k)), Tb) -
                    relativePoseResidual(Z, Ta * expSE3(-h * unit(k)), Tb)) / (2 * h);
    Jb_fd.col(k) = (relativePoseResidual(Z, Ta, Tb * expSE3(h * unit(k))) -
                    relativePoseResidual(Z, Ta, Tb * expSE3(-h * unit(k)))) / (2 * h);
  }
  // First order in e: the neglected terms are O(|e|) relative.
  EXPECT_LT((Ja - Ja_fd).norm(), 0.01 * Ja.norm());
  EXPECT_LT((Jb - Jb_fd).norm(), 0.01 * Jb.norm());
}

TEST_F(FeedbackTest, SolveRecoversPerturbedKeyframePoses) {
  FeedbackParams p;
  p.window = 4;
  p.iterations = 10;
  PoseWindow window(p);
  const std::vector<size_t> ids = {4, 12, 20, 28};
  std::vector<Eigen::Isometry3d> truth;
  for (size_t k = 0; k < ids.size(); ++k) {
    WindowKeyframe kf = keyframe(ids[k]);
    truth.push_back(kf.T_world_cam);
    // Tracking error: about 1.5 cm and 0.8 degrees, different per keyframe.
    const double s = k % 2 ? 1.0 : -1.0;
    kf.T_world_cam = kf.T_world_cam * expSE3((Vector6d() << 0.8 * kDeg * s, 0.5 * kDeg, -0.4 * kDeg * s, 0.012,
                                              -0.008 * s, 0.006).finished());
    window.add(std::move(kf), maps());
  }
  const SolveReport rep = window.solve(maps());
  ASSERT_TRUE(rep.failure.empty()) << rep.failure;
  EXPECT_GT(rep.accepted, 0);
  EXPECT_LT(rep.after.cost, 0.2 * rep.before.cost);
  EXPECT_GT(rep.after.depth_explicit, 4 * 1000);
  EXPECT_GT(rep.after.photo_explicit, 4 * 250);
  EXPECT_EQ(rep.after.depth_implicit, 0);
  for (size_t k = 0; k < ids.size(); ++k) {
    const Eigen::Isometry3d err = truth[k].inverse() * window.keyframes()[k].T_world_cam;
    EXPECT_LT(translationNorm(err), 0.003) << "keyframe " << k << " it " << rep.iterations << " acc " << rep.accepted
                                           << " cost " << rep.before.cost << " -> " << rep.after.cost << " rot "
                                           << rotationAngle(err) / kDeg;
    EXPECT_LT(rotationAngle(err) / kDeg, 0.15) << "keyframe " << k;
    const Eigen::Isometry3d before = truth[k].inverse() * rep.poses_before[k];
    EXPECT_GT(translationNorm(before), 0.012);
  }
}

// The TSDF's own surface inside a box, answered as an implicit field would
// be: every ray whose explicit hit lies in the box gets implicit residuals.
class TsdfSurface : public ImplicitSurface {
 public:
  TsdfSurface(const TsdfMap& map, const Eigen::AlignedBox3f& box) : map_(map), box_(box) {}
  const Eigen::AlignedBox3f& box() const override { return box_; }
  bool intersect(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float t_hint, float& t, Eigen::Vector3f& n,
                 Eigen::Vector3f& rgb) const override {
    BlockCache cache(map_);
    float ta = t_hint - 0.03f, tb = t_hint + 0.03f, sa = 0, sb = 0;
    if (!cache.sample(o + ta * d, 0, sa) || !cache.sample(o + tb * d, 0, sb) || !(sa > 0 && sb <= 0)) return false;
    for (int k = 0; k < 30; ++k) {
      const float tm = 0.5f * (ta + tb);
      float sm = 0;
      if (!cache.sample(o + tm * d, 0, sm)) return false;
      (sm > 0 ? ta : tb) = tm;
    }
    t = 0.5f * (ta + tb);
    float sdf = 0;
    return cache.sampleWithGradient(o + t * d, 0, sdf, n, rgb);
  }

 private:
  const TsdfMap& map_;
  Eigen::AlignedBox3f box_;
};

TEST_F(FeedbackTest, ImplicitChannelsCountOnlyInsideRefinedRegions) {
  FeedbackParams p;
  p.window = 2;
  PoseWindow window(p);
  window.add(keyframe(8), maps());
  const WindowKeyframe& kf = window.keyframes()[0];
  const std::vector<Eigen::Vector2i>& pixels = window.basePixels(0);
  // A refined region: the half of the space left of the keyframe's center
  // of view; elsewhere no field.
  BlockCache cache(*map_);
  std::vector<Eigen::Vector3d> hits;
  for (const auto& px : pixels) {
    SurfaceHit h;
    if (castExplicit(cache, *map_, cam_, kf.T_world_cam, px.x(), px.y(), kf.depth.at<float>(px.y(), px.x()),
                     p.max_incidence_deg, h)) {
      hits.push_back(h.point_world);
    }
  }
  ASSERT_GT(hits.size(), 500u);
  std::vector<double> xs;
  for (const auto& h : hits) xs.push_back(h.x());
  const float split = static_cast<float>(median(xs));
  const Eigen::AlignedBox3f box(Eigen::Vector3f(-100, -100, -100), Eigen::Vector3f(split, 100, 100));
  int inside = 0;
  for (const auto& h : hits) inside += box.contains(h.cast<float>());
  const TsdfSurface field(*map_, box);
  const auto L_none = window.linearize(0, kf.T_world_cam, maps(), pixels);
  const auto L_with = window.linearize(0, kf.T_world_cam, {map_, {&field}}, pixels);
  EXPECT_EQ(L_none.counts.depth_implicit, 0);
  EXPECT_EQ(L_with.counts.depth_explicit, L_none.counts.depth_explicit);
  // The field is the same surface: (nearly) every ray hitting inside the box
  // gets an implicit depth residual, none outside.
  EXPECT_LE(L_with.counts.depth_implicit, inside);
  EXPECT_GE(L_with.counts.depth_implicit, inside * 95 / 100) << inside;
  EXPECT_GT(L_with.counts.photo_implicit, 0);
  // At the true pose both channels agree: the implicit ones add cost but
  // next to nothing to the gradient's direction.
  EXPECT_GT(L_with.cost, L_none.cost);
}

TEST_F(FeedbackTest, ChannelAgreementSeesAnImageThatDisagreesWithItsDepth) {
  // A keyframe whose color image is shifted 3 pixels against its depth (a
  // color camera a moment late, say), its pose exact: the photometric
  // channel pulls it off, the depth channel's cost rises, and the solution
  // is flagged. The same keyframe with its own image, started 1 cm off,
  // lowers both costs.
  FeedbackParams p;
  p.window = 2;
  p.odometry_information_scale = 0;
  p.lambda_photo_explicit = 2.0;
  for (const bool shifted : {true, false}) {
    PoseWindow window(p);
    WindowKeyframe kf = keyframe(14);
    if (shifted) {
      const cv::Mat M = (cv::Mat_<double>(2, 3) << 1, 0, 3, 0, 1, 0);
      cv::Mat moved;
      cv::warpAffine(kf.intensity, moved, M, kf.intensity.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      kf.intensity = moved;
    } else {
      kf.T_world_cam = kf.T_world_cam * expSE3((Vector6d() << 0, 0, 0, 0.01, -0.005, 0.004).finished());
    }
    window.add(std::move(kf), maps());
    const SolveReport rep = window.solve(maps());
    ASSERT_TRUE(rep.failure.empty());
    ASSERT_EQ(rep.channels_agree.size(), 1u);
    EXPECT_GT(rep.accepted, 0) << (shifted ? "shifted" : "own image");
    EXPECT_EQ(rep.channels_agree[0], !shifted) << (shifted ? "shifted image" : "own image");
  }
}

TEST_F(FeedbackTest, DenseCheckTakesAMoveTowardTheTruthAndRefusesOneAway) {
  // A keyframe rendered at its true pose, checked between the truth and
  // poses off it: a correction toward the truth passes, one away is
  // refused, including one so far that most residuals leave their gates
  // (which would lower an uncharged cost).
  FeedbackParams p;
  p.window = 2;
  PoseWindow window(p);
  WindowKeyframe kf = keyframe(14);
  const Eigen::Isometry3d truth = kf.T_world_cam;
  const cv::Mat shared_intensity = kf.intensity, original = kf.intensity.clone();
  window.add(std::move(kf), maps());
  EXPECT_EQ(cv::norm(shared_intensity, original, cv::NORM_INF), 0.0) << "the window blurs a copy, not the frame's image";
  const Eigen::Isometry3d near =
      truth * expSE3((Vector6d() << 0.3 * kDeg, -0.2 * kDeg, 0, 0.004, 0.003, -0.002).finished());
  const Eigen::Isometry3d far = truth * expSE3((Vector6d() << 10 * kDeg, 0, 0, 0.25, -0.2, 0.15).finished());

  const PoseWindow::Verification toward = window.verify(0, near, truth, maps());
  EXPECT_GT(toward.pixels, 240 * 180 / 4 / 2);  // every 2nd pixel both ways; most have depth
  EXPECT_TRUE(toward.passed) << toward.depth_from << " -> " << toward.depth_to << ", " << toward.photo_from << " -> "
                             << toward.photo_to;
  EXPECT_LT(toward.depth_to, 0.8 * toward.depth_from);
  const PoseWindow::Verification away = window.verify(0, truth, near, maps());
  EXPECT_FALSE(away.passed);
  const PoseWindow::Verification far_away = window.verify(0, near, far, maps());
  EXPECT_FALSE(far_away.passed) << far_away.depth_from << " -> " << far_away.depth_to;
  EXPECT_GT(far_away.depth_to, 2 * far_away.depth_from);
  // Uncharged, the far pose's few residuals left inside the gates cost
  // less than the near pose's.
  const PoseWindow::Linearization at_near = window.linearize(0, near, maps(), window.basePixels(0));
  const PoseWindow::Linearization at_far = window.linearize(0, far, maps(), window.basePixels(0));
  EXPECT_LT(at_far.counts.depth_explicit * 20, at_near.counts.depth_explicit);
  EXPECT_LT(at_far.depth_cost, at_near.depth_cost);

  int asked = 0;
  const PoseWindow::Verification cut = window.verify(0, near, truth, maps(), [&] { return ++asked > 2; });
  EXPECT_TRUE(cut.stopped);
  EXPECT_FALSE(cut.passed) << "not checked to the end";
  EXPECT_EQ(asked, 3) << "asked before each chunk";

  p.verify_stride = 0;  // no check: nothing to pass
  PoseWindow unchecked(p);
  unchecked.add(keyframe(14), maps());
  EXPECT_FALSE(unchecked.verify(0, near, truth, maps()).passed);
}

TEST_F(FeedbackTest, TangentPlanesReproduceTheCastAndFollowItNearby) {
  // The solve's steps between casts evaluate the residuals on the tangent
  // planes of the last cast: at the cast's pose exactly the cast, and a
  // step away (millimetres) close to a fresh cast.
  FeedbackParams p;
  p.window = 2;
  PoseWindow window(p);
  window.add(keyframe(10), maps());
  const Eigen::Isometry3d T_world_kf = window.keyframes()[0].T_world_cam;
  const std::vector<Eigen::Vector2i>& pixels = window.basePixels(0);
  const auto cast = window.linearize(0, T_world_kf, maps(), pixels);
  const auto planes = window.linearizeOnPlanes(0, T_world_kf, T_world_kf, maps(), pixels);
  ASSERT_GT(cast.counts.depth_explicit, 500);
  EXPECT_EQ(planes.counts.depth_explicit, cast.counts.depth_explicit);
  EXPECT_EQ(planes.counts.photo_explicit, cast.counts.photo_explicit);
  EXPECT_NEAR(planes.cost, cast.cost, 1e-6 * cast.cost);
  EXPECT_LT((planes.b - cast.b).norm(), 1e-6 * cast.b.norm() + 1e-9);
  EXPECT_LT((planes.H - cast.H).norm(), 1e-6 * cast.H.norm());

  // 3 mm and 0.2 degrees away: the cost rises on the planes about as it
  // does for a fresh cast, and the gradients point the same way.
  Vector6d xi;
  xi << 0.002, -0.002, 0.002, 0.002, 0.001, -0.002;
  const Eigen::Isometry3d T2 = T_world_kf * expSE3(xi);
  const auto fresh = window.linearize(0, T2, maps(), pixels);
  const auto moved = window.linearizeOnPlanes(0, T_world_kf, T2, maps(), pixels);
  const double rise_fresh = fresh.cost - cast.cost, rise_planes = moved.cost - cast.cost;
  std::printf("cost at the cast %.1f; 3 mm away: fresh cast %.1f, planes %.1f; gradient cosine %.4f\n", cast.cost,
              fresh.cost, moved.cost, moved.b.normalized().dot(fresh.b.normalized()));
  ASSERT_GT(rise_fresh, 0.0);
  EXPECT_NEAR(rise_planes, rise_fresh, 0.1 * rise_fresh);
  EXPECT_GT(moved.b.normalized().dot(fresh.b.normalized()), 0.99);
}

TEST_F(FeedbackTest, MarginalizationIsTheSchurComplementOfTheOldestPose) {
  FeedbackParams p;
  p.window = 2;
  p.odometry_information_scale = 1.0;
  PoseWindow window(p);
  WindowKeyframe a = keyframe(6), b = keyframe(14), c = keyframe(22);
  Matrix6d info = Matrix6d::Identity() * 1e4;
  info(0, 1) = info(1, 0) = 2e3;
  b.odometry_from_previous = a.T_world_cam.inverse() * b.T_world_cam *
                             expSE3((Vector6d() << 1e-3, 0, -1e-3, 2e-3, 1e-3, 0).finished());
  b.odometry_information = info;
  c.odometry_from_previous = b.T_world_cam.inverse() * c.T_world_cam;
  c.odometry_information = info;
  // a slightly off, so that its residual factor has a gradient.
  a.T_world_cam = a.T_world_cam * expSE3((Vector6d() << 0.002, 0, 0, 0.004, 0, 0).finished());
  window.add(a, maps());
  window.add(b, maps());
  const std::vector<Eigen::Vector2i> a_pixels = window.basePixels(0);
  // Expected: the dense 12x12 system of a's factors, a eliminated.
  const auto La = window.linearize(0, window.keyframes()[0].T_world_cam, maps(), a_pixels);
  Matrix6d Ja, Jb;
  const Vector6d e = relativePoseResidual(window.keyframes()[1].odometry_from_previous,
                                          window.keyframes()[0].T_world_cam, window.keyframes()[1].T_world_cam, &Ja, &Jb);
  const Matrix6d Haa = La.H + Ja.transpose() * info * Ja, Hab = Ja.transpose() * info * Jb,
                 Hbb = Jb.transpose() * info * Jb;
  const Vector6d ba = La.b + Ja.transpose() * info * e, bb = Jb.transpose() * info * e;
  const Matrix6d H_expected = Hbb - Hab.transpose() * Haa.inverse() * Hab;
  const Vector6d b_expected = bb - Hab.transpose() * Haa.inverse() * ba;
  window.add(c, maps());  // a slides out
  ASSERT_EQ(window.size(), 2u);
  EXPECT_EQ(window.keyframes()[0].id, 14u);
  ASSERT_TRUE(window.hasPrior());
  EXPECT_LT((window.priorInformation() - H_expected).norm(), 1e-6 * H_expected.norm());
  EXPECT_LT((window.priorGradient() - b_expected).norm(), 1e-6 * std::max(1.0, b_expected.norm()));
  // The prior is a proper Gaussian: symmetric, positive semi-definite.
  const Eigen::SelfAdjointEigenSolver<Matrix6d> es(window.priorInformation());
  EXPECT_GT(es.eigenvalues().minCoeff(), -1e-6 * es.eigenvalues().maxCoeff());
}

}  // namespace
}  // namespace hxmap::alg
