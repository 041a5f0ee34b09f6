// Implicit refinement (paper 3.3): every layer and the full loss against
// finite differences; the untrained field reproduces the TSDF; training on
// keyframes moves a biased surface to the observed one and write-back
// carries that into the map without a seam; bad keyframes are skipped.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "hxmap/implicit/activation.hpp"
#include "hxmap/implicit/refine.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {
namespace {

const PinholeCamera kCam{80, 80, 39.5, 29.5, 80, 60, {0, 0, 0, 0, 0}};
constexpr float kVoxel = 0.02f;

TsdfParams tsdfParams() {
  TsdfParams p;
  p.voxel_size_m = kVoxel;
  p.truncation_m = 0.06;
  p.integration_level = 0;
  return p;
}

// Camera at `eye` looking at `target` (y down in the image).
Eigen::Isometry3f lookAt(const Eigen::Vector3f& eye, const Eigen::Vector3f& target) {
  const Eigen::Vector3f z = (target - eye).normalized();
  const Eigen::Vector3f x = Eigen::Vector3f::UnitY().cross(z).normalized() * -1.0f;
  const Eigen::Vector3f y = z.cross(x);
  Eigen::Isometry3f T_world_cam = Eigen::Isometry3f::Identity();
  T_world_cam.linear() << x, y, z;
  T_world_cam.translation() = eye;
  return T_world_cam;
}

// Depth and normals of the plane z = plane_z (world) seen from T; color a
// checker so that the photometric term has something to say.
KeyframeImages planeView(uint32_t id, const Eigen::Isometry3f& T_world_cam, float plane_z) {
  KeyframeImages k;
  k.id = id;
  k.camera = kCam;
  k.T_world_cam = T_world_cam;
  k.depth = cv::Mat(kCam.height, kCam.width, CV_32F, cv::Scalar(0.0f));
  k.rgb = cv::Mat(kCam.height, kCam.width, CV_8UC3, cv::Scalar(0, 0, 0));
  k.normal = cv::Mat(kCam.height, kCam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  const Eigen::Matrix3f R_cw = T_world_cam.linear().transpose();
  const Eigen::Vector3f n_cam =
      R_cw * Eigen::Vector3f(0, 0, -1);  // the plane faces the cameras (they sit at z < plane)
  for (int v = 0; v < kCam.height; ++v) {
    for (int u = 0; u < kCam.width; ++u) {
      const Eigen::Vector3f ray_c = kCam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
      const Eigen::Vector3f ray_w = T_world_cam.linear() * ray_c;
      if (ray_w.z() <= 1e-3f) continue;
      const float s = (plane_z - T_world_cam.translation().z()) / ray_w.z();  // z_cam = s
      const Eigen::Vector3f p = T_world_cam.translation() + s * ray_w;
      k.depth.at<float>(v, u) = s;
      const bool dark = (static_cast<int>(std::floor(p.x() / 0.05f)) + static_cast<int>(std::floor(p.y() / 0.05f))) & 1;
      k.rgb.at<cv::Vec3b>(v, u) = dark ? cv::Vec3b(40, 60, 80) : cv::Vec3b(200, 180, 160);
      k.normal.at<cv::Vec3f>(v, u) = cv::Vec3f(n_cam.x(), n_cam.y(), n_cam.z());
    }
  }
  return k;
}

void fuse(TsdfMap& map, const KeyframeImages& k) {
  DepthObservation obs;
  obs.depth_m = k.depth;
  obs.rgb = k.rgb;
  obs.camera = k.camera;
  obs.T_world_cam = k.T_world_cam;
  integrate(map, obs);
}

std::vector<Eigen::Isometry3f> viewPoses() {
  const Eigen::Vector3f target(0.08f, 0.08f, 0.5f);
  return {lookAt({0.08f, 0.08f, 0.0f}, target), lookAt({-0.15f, 0.1f, 0.05f}, target),
          lookAt({0.3f, 0.0f, 0.05f}, target), lookAt({0.1f, 0.3f, 0.05f}, target)};
}

ImplicitParams smallParams() {
  ImplicitParams p;
  p.rays_per_iteration = 96;
  p.samples_per_ray = 12;
  p.regularizer_points = 24;
  p.fuse_width = 8;
  p.hidden_width = 16;
  return p;
}

// A trained-looking field: decoder output weights away from zero so every
// path carries gradient.
void perturbDecoder(NeuralField& f, uint64_t seed) {
  std::mt19937 rng(static_cast<uint32_t>(seed));
  std::uniform_real_distribution<float> u(-0.3f, 0.3f);
  auto& P = f.parameters();
  for (size_t i = f.gridParameters(); i < P.size(); ++i) P[i] += 0.2f * u(rng);
  for (size_t i = f.fineOffset(); i < f.gridParameters(); ++i) P[i] += 0.05f * u(rng);
}

// Also through the kernels' remainders: 5 outputs (4 at a time), 5 inputs
// (2 at a time), 13 points (8 lanes, padded to 16).
TEST(ImplicitLayers, DenseLayerMatchesFiniteDifferences) {
  const int out = 5, in = 5, n = 13;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<float> W(out * in), b(out);
  for (auto& w : W) w = u(rng);
  for (auto& x : b) x = u(rng);
  PointRows X, Rw;
  X.resize(in, n);
  X.setZero();
  Rw.resize(out, n);
  Rw.setZero();
  for (int r = 0; r < in; ++r)
    for (int j = 0; j < n; ++j) X.row(r)[j] = u(rng);
  for (int r = 0; r < out; ++r)
    for (int j = 0; j < n; ++j) Rw.row(r)[j] = u(rng);
  // L = sum(Rw .* softplus(W X + b)) over the points (not the pads)
  auto loss = [&](const std::vector<float>& Wv, const std::vector<float>& bv, const PointRows& Xv) {
    PointRows A, Y, S;
    denseForward(Wv.data(), bv.data(), out, in, Xv, A);
    Y.resize(out, n);
    S.resize(out, n);
    softplusAndSlope(A.data(), Y.data(), S.data(), A.size());
    double sum = 0;
    for (int r = 0; r < out; ++r)
      for (int j = 0; j < n; ++j) sum += static_cast<double>(Y.row(r)[j]) * Rw.row(r)[j];
    return sum;
  };
  PointRows A, Y, S;
  denseForward(W.data(), b.data(), out, in, X, A);
  ASSERT_EQ(A.rows(), out);
  ASSERT_EQ(A.stride(), 16u);
  Y.resize(out, n);
  S.resize(out, n);
  softplusAndSlope(A.data(), Y.data(), S.data(), A.size());
  PointRows dA;
  dA.resize(out, n);
  for (size_t i = 0; i < dA.size(); ++i) dA.data()[i] = Rw.data()[i] * S.data()[i];  // pads: Rw is 0 there
  std::vector<float> dW(out * in, 0.0f), db(out, 0.0f);
  PointRows dX;
  denseBackward(W.data(), out, in, X, dA, dW.data(), db.data(), &dX);
  ASSERT_EQ(dX.rows(), in);
  const float eps = 1e-2f;
  for (int i = 0; i < out * in; ++i) {
    auto Wp = W, Wm = W;
    Wp[i] += eps, Wm[i] -= eps;
    EXPECT_NEAR(dW[i], (loss(Wp, b, X) - loss(Wm, b, X)) / (2 * eps), 2e-3) << "W " << i;
  }
  for (int i = 0; i < out; ++i) {
    auto bp = b, bm = b;
    bp[i] += eps, bm[i] -= eps;
    EXPECT_NEAR(db[i], (loss(W, bp, X) - loss(W, bm, X)) / (2 * eps), 2e-3) << "b " << i;
  }
  for (int r = 0; r < in; ++r) {
    for (int j = 0; j < n; ++j) {
      PointRows Xp = X, Xm = X;
      Xp.row(r)[j] += eps, Xm.row(r)[j] -= eps;
      EXPECT_NEAR(dX.row(r)[j], (loss(W, b, Xp) - loss(W, b, Xm)) / (2 * eps), 2e-3) << "X " << r << " " << j;
    }
  }
  // The input gradient of only the first rows is the same.
  PointRows dX2;
  denseBackward(W.data(), out, in, X, dA, dW.data(), db.data(), &dX2, 2);
  ASSERT_EQ(dX2.rows(), 2);
  for (int r = 0; r < 2; ++r)
    for (int j = 0; j < n; ++j) EXPECT_FLOAT_EQ(dX2.row(r)[j], dX.row(r)[j]);
}

// The activation's polynomials against the definitions in double precision,
// over the whole range a pre-activation can take, through the vectorized
// loop (every lane, and the remainder) and the scalar building blocks.
TEST(ImplicitLayers, SoftplusAndSlopeAgreeWithTheirDefinitions) {
  std::vector<float> a;
  for (float x = -100.0f; x <= 100.0f; x += 0.00731f) a.push_back(x);
  for (float x : {0.0f, -0.0f, 1e-30f, -1e-30f, 1e-7f, -1e-7f, 20.0f, -20.0f, 86.0f, -86.0f, 87.5f, -87.5f, 1e6f, -1e6f,
                  3.4e38f, -3.4e38f}) {
    a.push_back(x);
  }
  std::vector<float> sp(a.size()), slope(a.size());
  softplusAndSlope(a.data(), sp.data(), slope.data(), a.size());
  double worst_sp = 0, worst_slope = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double x = a[i];
    const double want_sp = std::max(x, 0.0) + std::log1p(std::exp(-std::abs(x)));
    const double want_slope = 1.0 / (1.0 + std::exp(-x));
    ASSERT_TRUE(std::isfinite(sp[i]) && std::isfinite(slope[i])) << x;
    // Relative, except below e^-86 (~4.5e-38), where the exponential is
    // clamped (a normal float's floor, for speed).
    const double floor = 4.5e-38;  // e^-86 = 4.47e-38
    auto error = [floor](double got, double want) {
      const double excess = std::abs(got - want) - floor;
      return excess > 0.0 ? excess / want : 0.0;
    };
    const double e_sp = error(sp[i], want_sp), e_slope = error(slope[i], want_slope);
    worst_sp = std::max(worst_sp, e_sp);
    worst_slope = std::max(worst_slope, e_slope);
    EXPECT_LT(e_sp, 4e-7) << "softplus at " << x << ": " << sp[i] << " against " << want_sp;
    EXPECT_LT(e_slope, 4e-7) << "slope at " << x << ": " << slope[i] << " against " << want_slope;
  }
  char worst[64];
  std::snprintf(worst, sizeof worst, "%.2e / %.2e", worst_sp, worst_slope);
  RecordProperty("worst_relative_error_softplus_slope", worst);
  for (float x = -86.0f; x <= 0.0f; x += 0.0013f) {
    const double want = std::exp(static_cast<double>(x));
    EXPECT_LT(std::abs(expNonPositive(x) - want) / want, 3e-7) << x;
  }
  for (float y = 0.0f; y <= 1.0f; y += 1.7e-5f) {
    const double want = std::log1p(static_cast<double>(y));
    EXPECT_LE(std::abs(log1pUnit(y) - want), 3e-7 * std::max(want, 1e-30)) << y;
  }
  EXPECT_EQ(log1pUnit(1e-30f), 1e-30f);
}

TEST(ImplicitLayers, TrilinearGridIsExactOnLinearFunctionsAndClampsOutside) {
  GridLayout g{Eigen::Vector3f(0.1f, -0.2f, 0.3f), 0.05f, Eigen::Vector3i(4, 5, 6), 1};
  std::vector<float> values(g.nodeCount());
  auto f = [](const Eigen::Vector3f& p) { return 2.0f * p.x() - 3.0f * p.y() + 0.5f * p.z() + 1.0f; };
  for (int z = 0; z < 6; ++z)
    for (int y = 0; y < 5; ++y)
      for (int x = 0; x < 4; ++x) values[(z * 5 + y) * 4 + x] = f(g.origin + g.cell * Eigen::Vector3f(x, y, z));
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3f p = g.origin + g.cell * Eigen::Vector3f(3 * u(rng), 4 * u(rng), 5 * u(rng));
    const Corners c = locate(g, p);
    float v = 0, wsum = 0;
    for (int k = 0; k < 8; ++k) v += c.weight[k] * values[c.node[k]], wsum += c.weight[k];
    EXPECT_NEAR(wsum, 1.0f, 1e-5f);
    EXPECT_NEAR(v, f(p), 1e-4f);
  }
  const Corners far = locate(g, Eigen::Vector3f(100, 100, 100));  // clamped to the last node
  float v = 0;
  for (int k = 0; k < 8; ++k) v += far.weight[k] * values[far.node[k]];
  EXPECT_NEAR(v, values.back(), 1e-4f);
}

// A job trained for all of p.iterations (no early stop), and its result.
RefineResult trainFully(const TsdfMap& map, const Eigen::AlignedBox3f& box,
                        const std::vector<KeyframeImages>& keyframes, ImplicitParams p) {
  p.convergence_rel = 0;
  RoiRefiner refiner(map, box, keyframes, p);
  while (refiner.iterate(10)) {
  }
  return refiner.result();
}

class PlaneScene : public ::testing::Test {
 protected:
  // The map is fused from views of a plane 1.2 cm behind where the
  // keyframes see it (a systematic error fusion cannot undo).
  void SetUp() override {
    for (const auto& T : viewPoses()) fuse(map_, planeView(0, T, kTrueZ + kBias));
    uint32_t id = 0;
    for (const auto& T : viewPoses()) keyframes_.push_back(planeView(id++, T, kTrueZ));
    box_ = Eigen::AlignedBox3f(Eigen::Vector3f(0.0f, 0.0f, 0.40f), Eigen::Vector3f(0.16f, 0.16f, 0.60f));
  }
  static constexpr float kTrueZ = 0.5f, kBias = 0.012f;
  TsdfMap map_{tsdfParams()};
  std::vector<KeyframeImages> keyframes_;
  Eigen::AlignedBox3f box_;
};

TEST_F(PlaneScene, UntrainedFieldIsTheTsdf) {
  const ImplicitParams p = smallParams();
  NeuralField f(map_, map_.voxelOf(box_.min()), Eigen::Vector3i(8, 8, 10), p);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  int compared = 0;
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3f q =
        f.box().min() + (f.box().max() - f.box().min()).cwiseProduct(Eigen::Vector3f(u(rng), u(rng), u(rng)));
    float expected = 0;
    if (!map_.sample(q, 0.0f, expected)) continue;
    Eigen::Matrix3Xf pts(3, 1);
    pts.col(0) = q;
    Eigen::VectorXf s;
    Eigen::Matrix3Xf rgb;
    f.forward(pts, s, &rgb, nullptr);
    EXPECT_NEAR(s[0], expected, 1e-5f);
    ++compared;
  }
  EXPECT_GT(compared, 100);
}

TEST_F(PlaneScene, FieldBackwardMatchesFiniteDifferences) {
  NeuralField f(map_, map_.voxelOf(box_.min()), Eigen::Vector3i(8, 8, 10), smallParams());
  perturbDecoder(f, 11);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const int n = 16;
  Eigen::Matrix3Xf pts(3, n);
  for (int j = 0; j < n; ++j) {
    pts.col(j) = f.box().min() + (f.box().max() - f.box().min()).cwiseProduct(Eigen::Vector3f(u(rng), u(rng), u(rng)));
  }
  Eigen::VectorXf a(n);
  Eigen::Matrix3Xf b(3, n);
  for (int j = 0; j < n; ++j)
    a[j] = u(rng) - 0.5f, b.col(j) = Eigen::Vector3f(u(rng), u(rng), u(rng)) - Eigen::Vector3f::Constant(0.5f);
  auto loss = [&]() {
    Eigen::VectorXf s;
    Eigen::Matrix3Xf c;
    f.forward(pts, s, &c, nullptr);
    return static_cast<double>(a.dot(s) / kVoxel + (b.cwiseProduct(c)).sum());
  };
  NeuralField::Cache cache;
  Eigen::VectorXf s;
  Eigen::Matrix3Xf c;
  f.forward(pts, s, &c, &cache);
  std::vector<float> grad(f.parameters().size(), 0.0f);
  TouchedNodes touched;
  touched.begin(f.nodeCount());
  f.backward(cache, a / kVoxel, b, grad, &touched);
  ASSERT_FALSE(touched.nodes().empty());
  // Each node once, and every node with a gradient listed.
  std::vector<int32_t> listed = touched.nodes();
  std::sort(listed.begin(), listed.end());
  EXPECT_EQ(std::adjacent_find(listed.begin(), listed.end()), listed.end());
  const auto coarse_nodes = static_cast<int32_t>(f.coarseGrid().nodeCount());
  for (size_t i = 0; i < f.gridParameters(); ++i) {
    if (grad[i] == 0.0f) continue;
    const auto node =
        static_cast<int32_t>(i < f.fineOffset() ? i / NeuralField::kCoarseStride : coarse_nodes + (i - f.fineOffset()));
    EXPECT_TRUE(std::binary_search(listed.begin(), listed.end(), node)) << "parameter " << i;
  }
  // Every parameter with a gradient, and a spread of the others.
  int checked = 0;
  auto& P = f.parameters();
  for (size_t i = 0; i < P.size(); ++i) {
    if (grad[i] == 0.0f && i % 97 != 0) continue;
    const float eps = 2e-3f, keep = P[i];
    P[i] = keep + eps;
    const double lp = loss();
    P[i] = keep - eps;
    const double lm = loss();
    P[i] = keep;
    const double fd = (lp - lm) / (2 * eps);
    EXPECT_NEAR(grad[i], fd, 2e-2 + 2e-2 * std::abs(fd)) << "parameter " << i << " of " << P.size();
    ++checked;
  }
  EXPECT_GT(checked, 200);
}

TEST_F(PlaneScene, LossGradientMatchesFiniteDifferences) {
  ImplicitParams p = smallParams();
  p.rays_per_iteration = 24;
  NeuralField f(map_, map_.voxelOf(box_.min()), Eigen::Vector3i(8, 8, 10), p);
  perturbDecoder(f, 13);
  // With free-space rays (every ray that crosses the box to the plane
  // beyond it), a quarter of the batch.
  const std::vector<TrainingRay> rays = collectRays(keyframes_, f.box(), p, [](const TrainingRay&) { return true; });
  ASSERT_GT(rays.size(), 100u);
  uint64_t rng = 3;
  const RenderBatch batch = sampleBatch(f, rays, {}, p, true, rng);
  int free_rays = 0;
  for (int32_t i : batch.rays) free_rays += rays[static_cast<size_t>(i)].free_space;
  EXPECT_EQ(free_rays, 6);
  std::vector<float> grad(f.parameters().size(), 0.0f);
  TouchedNodes touched;
  touched.begin(f.nodeCount());
  const LossTerms L = evaluateLoss(f, rays, batch, p, &grad, &touched);
  EXPECT_GT(L.depth, 0.0);
  EXPECT_GT(L.photo, 0.0);
  EXPECT_GT(L.normal_points, 0);
  EXPECT_GT(L.eikonal, 0.0);
  // The largest gradients (where the loss actually depends on the
  // parameter) and a spread of decoder weights.
  std::vector<size_t> order(grad.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::partial_sort(order.begin(), order.begin() + 150, order.end(),
                    [&](size_t x, size_t y) { return std::abs(grad[x]) > std::abs(grad[y]); });
  std::vector<size_t> check(order.begin(), order.begin() + 150);
  for (size_t i = f.gridParameters(); i < grad.size(); i += 7) check.push_back(i);
  auto& P = f.parameters();
  double scale = 0;
  for (size_t i : check) scale = std::max(scale, static_cast<double>(std::abs(grad[i])));
  int bad = 0;
  for (size_t i : check) {
    const float eps = 1e-3f, keep = P[i];
    P[i] = keep + eps;
    const double lp = evaluateLoss(f, rays, batch, p).total;
    P[i] = keep - eps;
    const double lm = evaluateLoss(f, rays, batch, p).total;
    P[i] = keep;
    const double fd = (lp - lm) / (2 * eps);
    // A clamped opacity or a Huber corner between the two probes can bend
    // a difference; such parameters are rare, a wrong derivative is not.
    if (std::abs(grad[i] - fd) > 0.05 * std::abs(fd) + 0.02 * scale) {
      ++bad;
      if (bad <= 5) std::printf("parameter %zu: analytic %.6g, finite difference %.6g\n", i, grad[i], fd);
    }
  }
  EXPECT_LE(bad, static_cast<int>(check.size() / 50)) << "of " << check.size() << " parameters";
}

float surfaceZ(const TsdfMap& map, float x, float y) {
  // The zero crossing of the map's SDF along +z.
  float prev = 0;
  bool have = false;
  for (float z = 0.42f; z < 0.58f; z += 0.001f) {
    float s = 0;
    if (!map.sample(Eigen::Vector3f(x, y, z), 0.0f, s)) {
      have = false;
      continue;
    }
    if (have && prev > 0 && s <= 0) return z - 0.001f * s / (s - prev);
    prev = s, have = true;
  }
  return NAN;
}

TEST_F(PlaneScene, TrainingMovesTheSurfaceToTheObservationsAndWritesItBack) {
  const float before = surfaceZ(map_, 0.08f, 0.08f);
  ASSERT_NEAR(before, kTrueZ + kBias, 0.004f);
  ImplicitParams p = smallParams();
  p.iterations = 80;
  p.convergence_rel = 0;  // run all iterations
  RoiRefiner refiner(map_, box_, keyframes_, p);
  ASSERT_GT(refiner.rays().size(), 1000u);
  while (refiner.iterate(5)) {
  }
  EXPECT_EQ(refiner.iterations(), 80);
  RefineResult r = refiner.result();
  EXPECT_LT(r.stats.last.depth, r.stats.first.depth * 0.5);
  EXPECT_NEAR(r.stats.depth_l1_before_m, kBias, 0.004);  // the TSDF renders 1.2 cm off
  EXPECT_LT(r.stats.depth_l1_after_m, 0.5 * r.stats.depth_l1_before_m);
  EXPECT_FALSE(r.neural_sigma.empty());
  ASSERT_FALSE(r.patch.entries.empty());

  TsdfMap refined = map_;
  const PatchStats ps = applyPatch(refined, r.patch);
  EXPECT_EQ(ps.rejected, 0u);
  const float after = surfaceZ(refined, 0.08f, 0.08f);
  // ratio 4: the voxel takes 4/5 of the refined value.
  EXPECT_LT(std::abs(after - kTrueZ), 0.5f * std::abs(before - kTrueZ)) << "before " << before << " after " << after;
  // No seam: outside the box the map is untouched, and at the box border
  // the correction fades out.
  const float outside = surfaceZ(refined, 0.25f, 0.08f);
  EXPECT_NEAR(outside, surfaceZ(map_, 0.25f, 0.08f), 1e-5f);
  const float border = surfaceZ(refined, 0.005f, 0.08f);
  EXPECT_GT(std::abs(border - kTrueZ), std::abs(after - kTrueZ));
}

TEST_F(PlaneScene, KeyframeNoiseAloneBarelyMovesTheMap) {
  // The map is fused from the true plane; the keyframes see it with 1 cm
  // zero-mean noise per pixel. The field can fit that noise, but the TSDF
  // (which averaged its frames) has no bias to correct: write-back must
  // leave the surface close to where it was.
  TsdfMap clean{tsdfParams()};
  for (int rep = 0; rep < 8; ++rep) {
    for (const auto& T : viewPoses()) fuse(clean, planeView(0, T, kTrueZ));
  }
  std::mt19937 rng(17);
  std::normal_distribution<float> noise(0.0f, 0.01f);
  std::vector<KeyframeImages> noisy = keyframes_;
  for (auto& k : noisy) {
    k.depth = k.depth.clone();
    for (auto it = k.depth.begin<float>(); it != k.depth.end<float>(); ++it) {
      if (*it > 0) *it += noise(rng);
    }
  }
  ImplicitParams p = smallParams();
  p.iterations = 80;
  const RefineResult r = trainFully(clean, box_, noisy, p);
  ASSERT_FALSE(r.patch.entries.empty());
  // Every written voxel keeps most of its fused value: without a bias its
  // weight is one observation's, 1 / n of the TSDF's (32 frames), far below
  // the cap.
  for (const auto& e : r.patch.entries) {
    Voxel v;
    ASSERT_TRUE(clean.voxel(e.voxel, v));
    EXPECT_LT(e.weight, 0.5f * v.weight) << e.voxel.transpose();
  }
  TsdfMap refined = clean;
  applyPatch(refined, r.patch);
  double worst = 0;
  for (float x = 0.04f; x <= 0.12f; x += 0.02f) {
    for (float y = 0.04f; y <= 0.12f; y += 0.02f)
      worst = std::max(worst, std::abs(double(surfaceZ(refined, x, y)) - kTrueZ));
  }
  EXPECT_LT(worst, 0.002) << "the noise leaked into the map";
}

TEST_F(PlaneScene, AFieldThatRendersWorseThanTheTsdfWritesNothingBack) {
  // The map fused from the true plane, the keyframes exact: the TSDF
  // renders them within a fraction of a millimetre. A field trained with
  // learning rates far too high ends worse than that; no voxel of it may
  // reach the map.
  TsdfMap clean{tsdfParams()};
  for (int rep = 0; rep < 8; ++rep) {
    for (const auto& T : viewPoses()) fuse(clean, planeView(0, T, kTrueZ));
  }
  ImplicitParams p = smallParams();
  p.iterations = 40;
  p.learning_rate_grid = 1.0;
  p.learning_rate_mlp = 0.3;
  const RefineResult r = trainFully(clean, box_, keyframes_, p);
  EXPECT_GT(r.stats.depth_l1_after_m, 2.0 * r.stats.depth_l1_before_m) << "the field should have diverged";
  EXPECT_TRUE(r.patch.entries.empty()) << r.patch.entries.size() << " voxels written back";
}

TEST_F(PlaneScene, WriteBackOfAnUntrainedFieldKeepsTheMap) {
  ImplicitParams p = smallParams();
  EXPECT_TRUE(RoiRefiner(map_, box_, keyframes_, p).result().patch.entries.empty());  // no sample reached a voxel yet
  p.learning_rate_grid = p.learning_rate_mlp = 0;  // samples reach voxels, values stay
  RoiRefiner refiner(map_, box_, keyframes_, p);
  while (refiner.iterations() < 10) refiner.iterate(10);
  RefineResult r = refiner.result();
  ASSERT_FALSE(r.patch.entries.empty());
  TsdfMap same = map_;
  applyPatch(same, r.patch);
  for (const auto& e : r.patch.entries) {
    Voxel a, b;
    ASSERT_TRUE(map_.voxel(e.voxel, a));
    ASSERT_TRUE(same.voxel(e.voxel, b));
    EXPECT_NEAR(a.sdf_m, b.sdf_m, 1e-5f);
    EXPECT_LE(std::abs(a.color.r - b.color.r), 1);
  }
}

TEST_F(PlaneScene, APatchFusionNeverObservedIsCompletedFromTheKeyframes) {
  // The map is fused from the true plane, except a 6 x 6 cm patch whose
  // depth fusion never received (in the quality room, a shelf's top seen
  // only past the incidence fusion accepts). The keyframes see all of it.
  TsdfMap holed{tsdfParams()};
  for (int rep = 0; rep < 4; ++rep) {
    for (const auto& T : viewPoses()) {
      KeyframeImages k = planeView(0, T, kTrueZ);
      for (int v = 0; v < kCam.height; ++v) {
        for (int u = 0; u < kCam.width; ++u) {
          float& z = k.depth.at<float>(v, u);
          if (!(z > 0)) continue;
          const Eigen::Vector3f p = T * kCam.backproject(static_cast<float>(u), static_cast<float>(v), z);
          if (std::abs(p.x() - 0.08f) < 0.03f && std::abs(p.y() - 0.08f) < 0.03f) z = 0;
        }
      }
      fuse(holed, k);
    }
  }
  ASSERT_TRUE(std::isnan(surfaceZ(holed, 0.08f, 0.08f))) << "the patch should be empty";
  ASSERT_NEAR(surfaceZ(holed, 0.14f, 0.14f), kTrueZ, 0.003f);
  ImplicitParams p = smallParams();
  p.iterations = 120;
  const RefineResult r = trainFully(holed, box_, keyframes_, p);
  EXPECT_GT(r.stats.completed, 8u);  // 3 x 3 columns of voxels, two or more deep
  for (const auto& e : r.patch.entries) {
    Voxel v;
    if (holed.voxel(e.voxel, v) && v.weight > 0) continue;
    // One observation's worth (less in the border ramp), within the band.
    EXPECT_LE(e.weight, RoiRefiner::kCompletionWeight) << e.voxel.transpose();
    EXPECT_LT(std::abs(e.sdf_m), holed.truncation()) << e.voxel.transpose();
  }
  TsdfMap completed = holed;
  applyPatch(completed, r.patch);
  for (const float x : {0.07f, 0.08f, 0.09f}) {
    EXPECT_NEAR(surfaceZ(completed, x, 0.08f), kTrueZ, 0.004f) << "x " << x;
  }
  // The fused surface around the patch stays where it was.
  EXPECT_NEAR(surfaceZ(completed, 0.14f, 0.14f), surfaceZ(holed, 0.14f, 0.14f), 0.002f);
}

TEST(ShadowScene, RaysThatSawThroughAShadowClearItAndFusionKeepsItClear) {
  // The map holds a wall at z = 0.8 m and, inside the box, a 4 cm slab of
  // surface nothing observed: what fusion leaves behind a thin part, up to
  // mu deep. The keyframes see the wall through it. Refinement must clear
  // the slab from the free-space rays alone (no keyframe surface lies in
  // the box), flag it seen through, and later fusion of a view that puts
  // the slab behind a surface must not fill it again.
  TsdfMap map{tsdfParams()};
  std::vector<KeyframeImages> keyframes;
  uint32_t id = 0;
  for (const auto& T : viewPoses()) {
    keyframes.push_back(planeView(id++, T, 0.8f));
    fuse(map, keyframes.back());
  }
  const Eigen::AlignedBox3f box(Eigen::Vector3f(0.0f, 0.0f, 0.40f), Eigen::Vector3f(0.16f, 0.16f, 0.60f));
  const Eigen::AlignedBox3f slab(Eigen::Vector3f(0.04f, 0.04f, 0.50f), Eigen::Vector3f(0.12f, 0.12f, 0.54f));
  const float mu = map.truncation();
  TsdfPatch fill;
  std::vector<Eigen::Vector3i> inside;
  for (int z = 20; z < 30; ++z) {
    for (int y = 0; y < 8; ++y) {
      for (int x = 0; x < 8; ++x) {
        const Eigen::Vector3i v(x, y, z);
        const Eigen::Vector3f c = map.voxelCenter(v);
        const Eigen::Vector3f q = (c - slab.center()).cwiseAbs() - 0.5f * slab.sizes();
        const float d = q.cwiseMax(0.0f).norm() + std::min(q.maxCoeff(), 0.0f);  // box signed distance
        fill.entries.push_back({v, std::clamp(d, -mu, mu), 4.0f});               // four views' worth
        if (d < 0.0f) inside.push_back(v);
      }
    }
  }
  applyPatch(map, fill);
  ASSERT_EQ(inside.size(), 32u);
  // Slab voxels inside a surface; outside it (and flagged seen through).
  auto count = [&](const TsdfMap& m, bool outside_flagged) {
    int n = 0;
    for (const auto& v : inside) {
      Voxel vx;
      if (!m.voxel(v, vx)) continue;
      n += outside_flagged ? vx.sdf_m > 0.0f && (vx.color.flags & kVoxelSeenThrough) : vx.sdf_m < 0.0f;
    }
    return n;
  };
  ASSERT_EQ(count(map, false), 32);

  ImplicitParams p = smallParams();
  p.iterations = 120;
  RefineResult r = trainFully(map, box, keyframes, p);
  EXPECT_GT(r.stats.free_space_rays, 100u);
  EXPECT_EQ(r.stats.free_space_rays, r.stats.rays);
  TsdfMap refined = map;
  applyPatch(refined, r.patch);
  EXPECT_LE(count(refined, false), 3) << "of 32 slab voxels still inside a surface";
  const int flagged = count(refined, true);
  EXPECT_GE(flagged, 29);

  // A surface just in front of the slab (z = 0.485 m) seen head on, forty
  // times: the slab lies 2.5-4.5 cm behind it. Without the flags it fills
  // in.
  TsdfMap unflagged = map;
  for (auto& e : r.patch.entries) e.seen_through = false;
  applyPatch(unflagged, r.patch);
  const KeyframeImages occluder = planeView(99, viewPoses()[0], 0.485f);
  for (int i = 0; i < 40; ++i) {
    fuse(refined, occluder);
    fuse(unflagged, occluder);
  }
  EXPECT_EQ(count(refined, true), flagged) << "the slab stays clear";
  EXPECT_GE(count(unflagged, false), 16) << "without the flags fusion fills the slab again";
}

TEST_F(PlaneScene, BadKeyframesAreSkipped) {
  std::vector<KeyframeImages> bad;
  KeyframeImages nan = keyframes_[0];
  nan.depth = keyframes_[0].depth.clone();
  nan.depth.setTo(std::numeric_limits<float>::quiet_NaN());
  bad.push_back(nan);
  KeyframeImages wrong = keyframes_[1];
  wrong.depth = cv::Mat(10, 10, CV_16U, cv::Scalar(1000));  // not meters
  bad.push_back(wrong);
  KeyframeImages no_color = keyframes_[2];
  no_color.rgb = cv::Mat(5, 5, CV_8UC3);  // wrong size: depth only
  no_color.normal = cv::Mat();
  bad.push_back(no_color);
  bad.push_back(KeyframeImages{});  // empty
  const std::vector<TrainingRay> rays = collectRays(bad, box_, smallParams());
  ASSERT_FALSE(rays.empty());  // from the depth-only keyframe
  for (const auto& r : rays) {
    EXPECT_EQ(r.keyframe, keyframes_[2].id);
    EXPECT_FALSE(r.has_color);
    EXPECT_TRUE(std::isfinite(r.t_obs));
  }
  RoiRefiner nothing(map_, box_, {bad[0], bad[1], bad[3]}, smallParams());
  EXPECT_TRUE(nothing.finished());
  EXPECT_FALSE(nothing.iterate(5));
  EXPECT_EQ(nothing.iterations(), 0);
}

}  // namespace
}  // namespace hxmap::alg
