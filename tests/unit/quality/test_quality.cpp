// Quality indicators (paper eq 2-7): each fires where it should and stays
// quiet on a clean wall; normalization, budget and ROI grouping.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/quality/quality.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/raycast.hpp"

namespace hxmap::alg {
namespace {

// 160x120, the wall 2 m ahead spans x in [-1.33, 1.33] m; 2 cm voxels make
// 16 cm blocks, so the wall's samples land in block z = 12 (1.92-2.08 m).
const PinholeCamera kCam{120, 120, 79.5, 59.5, 160, 120, {0, 0, 0, 0, 0}};
constexpr float kWallZ = 2.0f;

TsdfParams tsdfParams() {
  TsdfParams p;
  p.voxel_size_m = 0.02;
  p.truncation_m = 0.08;
  return p;
}

QualityParams qualityParams() {
  QualityParams q;
  q.pixel_stride = 1;
  return q;
}

float pixelX(int u, float z) {
  return (static_cast<float>(u) - static_cast<float>(kCam.cx)) / static_cast<float>(kCam.fx) * z;
}

// Depth of the wall, with a per-pixel override.
template <typename F>
cv::Mat depthImage(F&& depth_at) {
  cv::Mat d(kCam.height, kCam.width, CV_32F);
  for (int v = 0; v < d.rows; ++v) {
    for (int u = 0; u < d.cols; ++u) d.at<float>(v, u) = depth_at(u, v);
  }
  return d;
}

FrameLevel frameLevel(const cv::Mat& depth) {
  FrameLevel f;
  f.camera = kCam;
  f.depth = depth;
  f.vertex = vertexMap(depth, kCam);
  f.normal = computeNormals(f.vertex, PreprocessParams{});
  f.intensity = cv::Mat(depth.size(), CV_32F, cv::Scalar(0.5f));
  return f;
}

// A model view that shows `depth` (identity pose): what a raycast of a map
// that reproduces it would return.
ModelView modelView(const cv::Mat& depth) {
  ModelView m;
  m.camera = kCam;
  m.depth = depth.clone();
  m.vertex_world = vertexMap(depth, kCam);
  cv::Mat n = computeNormals(m.vertex_world, PreprocessParams{});
  m.normal_world = n;
  return m;
}

// Mean raw indicator over the scored blocks that pass `select`.
template <typename F>
float meanRaw(const std::vector<BlockScore>& scores, int indicator, F&& select, int* count = nullptr) {
  double sum = 0;
  int n = 0;
  for (const auto& s : scores) {
    if (!select(s.key)) continue;
    sum += s.raw[indicator];
    ++n;
  }
  if (count) *count = n;
  return n ? static_cast<float>(sum / n) : -1.0f;
}

TEST(Quality, RmFiresWhereTheRenderingMissesTheInputAndNotOnACleanWall) {
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  const cv::Mat frame = depthImage([](int, int) { return kWallZ; });
  // The map's rendering is 5 cm behind the input for x in [0.32, 0.64] m.
  const cv::Mat model = depthImage([](int u, int) {
    const float x = pixelX(u, kWallZ);
    return x >= 0.32f && x < 0.64f ? kWallZ + 0.05f : kWallZ;
  });
  const FrameLevel f = frameLevel(frame);
  const ModelView m = modelView(model);
  const auto stats = quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &m});
  EXPECT_GT(stats.blocks_scored, 50u);
  const auto scores = quality.score(map.truncation());
  int n_bad = 0, n_clean = 0;
  const float bad = meanRaw(
      scores, kRm, [](const BlockKey& k) { return k.x() == 2 || k.x() == 3; }, &n_bad);
  const float clean = meanRaw(
      scores, kRm, [](const BlockKey& k) { return k.x() <= 0 || k.x() >= 5; }, &n_clean);
  ASSERT_GT(n_bad, 0);
  ASSERT_GT(n_clean, 0);
  // gamma_d * min(1, 5 cm / mu 8 cm) = 0.31; no photometric term without map colors.
  EXPECT_NEAR(bad, 0.5f * 0.05f / 0.08f, 0.01f);
  EXPECT_LT(clean, 1e-4f);
}

TEST(Quality, AMissAtTheImageBorderIsNotHeldAgainstTheMap) {
  // The rendering lacks the wall in the 3 columns at the image's left
  // border (voxels at the edge of the frustum, partly observed) and in the
  // middle strip x in [0.32, 0.64] m (the map is missing there).
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  const cv::Mat frame = depthImage([](int, int) { return kWallZ; });
  const cv::Mat model = depthImage([](int u, int) {
    const float x = pixelX(u, kWallZ);
    return u < 3 || (x >= 0.32f && x < 0.64f) ? 0.0f : kWallZ;
  });
  const FrameLevel f = frameLevel(frame);
  const ModelView m = modelView(model);
  quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &m});
  const auto scores = quality.score(map.truncation());
  int n_missing = 0, n_left = 0;
  const float missing = meanRaw(
      scores, kRm, [](const BlockKey& k) { return k.x() == 2 || k.x() == 3; }, &n_missing);
  float worst_left = 0;
  for (const auto& s : scores) {
    if (s.key.x() > 0) continue;
    worst_left = std::max(worst_left, s.raw[kRm]);
    ++n_left;
  }
  ASSERT_GT(n_missing, 0);
  ASSERT_GT(n_left, 0);
  EXPECT_NEAR(missing, 0.5f, 0.01f);  // gamma_d * min(1, mu / mu)
  EXPECT_LT(worst_left, 1e-4f) << "the border's misses counted";
}

TEST(Quality, ASurfaceBeyondTheFusionRangeIsNotHeldAgainstTheMap) {
  // The right half of the frame sees a wall 4.5 m away, beyond the map's
  // 4 m fusion range: the map has no surface there, and that is no error.
  TsdfParams tp = tsdfParams();
  tp.max_integration_depth_m = 4.0;
  TsdfMap map(tp);
  QualityMap quality(qualityParams());
  constexpr float kFar = 4.5f;
  const int half = kCam.width / 2;
  const cv::Mat frame = depthImage([&](int u, int) { return u < half ? kWallZ : kFar; });
  const cv::Mat model = depthImage([&](int u, int) { return u < half ? kWallZ : 0.0f; });
  const FrameLevel f = frameLevel(frame);
  const ModelView m = modelView(model);
  quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &m});
  const auto scores = quality.score(map.truncation());
  ASSERT_FALSE(scores.empty());
  float worst_rm = 0;
  for (const auto& s : scores) {
    EXPECT_LT(static_cast<float>(s.key.z()) * map.blockSize(), 4.0f) << "a block of the far wall was scored";
    worst_rm = std::max(worst_rm, s.raw[kRm]);
  }
  EXPECT_LT(worst_rm, 1e-4f);
}

TEST(Quality, ObgFlagsTheOccludersEdgeAndNotTheWallBehindIt) {
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  // A square 1.2 m away, |x|, |y| < 0.3 m, in front of the wall.
  const cv::Mat frame = depthImage([](int u, int v) {
    const float x = pixelX(u, 1.2f);
    const float y = (static_cast<float>(v) - static_cast<float>(kCam.cy)) / static_cast<float>(kCam.fy) * 1.2f;
    return std::abs(x) < 0.3f && std::abs(y) < 0.3f ? 1.2f : kWallZ;
  });
  const FrameLevel f = frameLevel(frame);
  const ModelView m = modelView(frame);
  quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &m});
  const auto scores = quality.score(map.truncation());
  float edge_max = 0;
  for (const auto& s : scores) {
    if (s.key.z() == 7 && (s.key.x() == -2 || s.key.x() == 1)) edge_max = std::max(edge_max, s.raw[kObg]);
  }
  int n_wall = 0;
  const float wall = meanRaw(
      scores, kObg, [](const BlockKey& k) { return k.z() == 12 && std::abs(k.x()) >= 4; }, &n_wall);
  ASSERT_GT(n_wall, 0);
  EXPECT_GE(edge_max, 0.5f * 0.99f);  // beta_o * B_occ, B_occ saturated
  EXPECT_LT(wall, 1e-4f);

  // D_var: a region whose mismatch flips sign between two views.
  QualityMap q2(qualityParams());
  for (int view = 0; view < 2; ++view) {
    const cv::Mat wall_depth = depthImage([](int, int) { return kWallZ; });
    const cv::Mat model = depthImage([&](int u, int) {
      const float x = pixelX(u, kWallZ);
      return x >= 0.32f && x < 0.64f ? kWallZ + (view ? 0.04f : -0.04f) : kWallZ;
    });
    const FrameLevel fv = frameLevel(wall_depth);
    const ModelView mv = modelView(model);
    q2.update(map, {static_cast<uint32_t>(view), Eigen::Isometry3f::Identity(), &fv, &mv});
  }
  const auto s2 = q2.score(map.truncation());
  const float varying = meanRaw(s2, kObg, [](const BlockKey& k) { return k.x() == 2 || k.x() == 3; });
  const float steady = meanRaw(s2, kObg, [](const BlockKey& k) { return k.x() <= 0; });
  // std of {-4, +4} cm over two views = 5.66 cm -> beta_d * 5.66 / 8 = 0.354
  EXPECT_NEAR(varying, 0.5f * 0.0566f / 0.08f, 0.01f);
  EXPECT_LT(steady, 1e-4f);
}

// Fuses `frames` depth images of the wall at the identity pose, then scores
// one keyframe against the raycast model.
std::vector<BlockScore> fuseAndScore(TsdfMap& map, QualityMap& quality, const std::vector<cv::Mat>& frames,
                                     const cv::Mat& keyframe) {
  for (const auto& d : frames) integrate(map, {d, cv::Mat(), cv::Mat(), kCam, Eigen::Isometry3f::Identity()});
  integrate(map, {keyframe, cv::Mat(), cv::Mat(), kCam, Eigen::Isometry3f::Identity()});
  const ModelView model = raycast(map, kCam, Eigen::Isometry3f::Identity(), RaycastParams{});
  const FrameLevel f = frameLevel(keyframe);
  quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &model});
  return quality.score(map.truncation());
}

TEST(Quality, CgnFiresOnSurfaceSeenOnceAndNotOnAConsolidatedWall) {
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  // Four keyframes see only the left half (x < 0) head on; the fifth sees it all.
  const cv::Mat left = depthImage([](int u, int) { return pixelX(u, kWallZ) < 0.0f ? kWallZ : 0.0f; });
  const cv::Mat full = depthImage([](int, int) { return kWallZ; });
  for (uint32_t id = 0; id < 5; ++id) {
    const cv::Mat& d = id < 4 ? left : full;
    integrate(map, {d, cv::Mat(), cv::Mat(), kCam, Eigen::Isometry3f::Identity()});
    const ModelView model = raycast(map, kCam, Eigen::Isometry3f::Identity(), RaycastParams{});
    const FrameLevel f = frameLevel(d);
    quality.update(map, {id, Eigen::Isometry3f::Identity(), &f, &model});
  }
  const auto scores = quality.score(map.truncation());
  int n_new = 0, n_old = 0;
  // Blocks away from the image's top and bottom rows, where the raycast
  // model (which the views are counted on) has fewer hits.
  const float fresh = meanRaw(
      scores, kCgn,
      [](const BlockKey& k) { return k.z() == 12 && k.x() >= 1 && k.x() <= 5 && k.y() >= -4 && k.y() <= 3; }, &n_new);
  const float old = meanRaw(
      scores, kCgn,
      [](const BlockKey& k) { return k.z() == 12 && k.x() <= -2 && k.x() >= -6 && k.y() >= -4 && k.y() <= 3; }, &n_old);
  ASSERT_GT(n_new, 0);
  ASSERT_GT(n_old, 0);
  // alpha_c * (1 - 1/3 usable views) = 0.33 where one keyframe saw the wall,
  // plus a little normal novelty; 0 where five did.
  EXPECT_NEAR(fresh, 0.5f * (1.0f - 1.0f / 3.0f), 0.03f);
  EXPECT_LT(old, 0.02f);
  const BlockQuality* seen_once = quality.find(BlockKey(3, 0, 12));
  ASSERT_NE(seen_once, nullptr);
  EXPECT_EQ(seen_once->good_views, 1u);
}

TEST(Quality, AViewOfASurfaceOnABlockFaceCountsForTheBlocksOnBothSides) {
  // The map's wall 3 mm behind z = 1.92 m, the face between blocks z = 11
  // and 12: all of its rendered surface lies in block 12, but it is the
  // zero crossing between voxels of both. The keyframes' depth alternates
  // between 8 mm behind and 2 mm in front of the face, so both blocks get
  // samples. Three head-on keyframes consolidate both (no coverage term).
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  const float face = 12 * map.blockSize();
  const cv::Mat d = depthImage([&](int u, int v) { return face + ((u + v) % 2 ? 0.008f : -0.002f); });
  const ModelView model = modelView(depthImage([&](int, int) { return face + 0.003f; }));
  for (uint32_t id = 0; id < 3; ++id) {
    integrate(map, {d, cv::Mat(), cv::Mat(), kCam, Eigen::Isometry3f::Identity()});
    const FrameLevel f = frameLevel(d);
    quality.update(map, {id, Eigen::Isometry3f::Identity(), &f, &model});
  }
  for (int bz : {11, 12}) {
    const BlockQuality* q = quality.find(BlockKey(0, 0, bz));
    ASSERT_NE(q, nullptr) << "block z " << bz;
    EXPECT_EQ(q->good_views, 3u) << "block z " << bz;
    EXPECT_EQ(q->coverage_new, 0.0f) << "block z " << bz;
  }
}

TEST(Quality, UfFiresOnNoisyDepthAndNotOnACleanWall) {
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  // Right half: 2 cm depth noise; left half: 1 mm.
  std::vector<cv::Mat> frames;
  for (int i = 0; i < 20; ++i) {
    frames.push_back(
        depthImage([&](int u, int) { return kWallZ + (pixelX(u, kWallZ) >= 0.0f ? 0.02f : 0.001f) * noise(rng); }));
  }
  const auto scores = fuseAndScore(map, quality, frames, frames.back());
  const float noisy = meanRaw(scores, kUf, [](const BlockKey& k) { return k.z() == 12 && k.x() >= 1 && k.x() <= 5; });
  const float clean = meanRaw(scores, kUf, [](const BlockKey& k) { return k.z() == 12 && k.x() <= -2 && k.x() >= -6; });
  ASSERT_GT(noisy, 0.0f);
  ASSERT_GE(clean, 0.0f);
  // sigma_TSDF / mu: about 2 cm / 8 cm on the noisy half, about 1 mm / 8 cm on the clean one.
  EXPECT_GT(noisy, 0.15f);
  EXPECT_LT(clean, 0.04f);
  EXPECT_GT(noisy, 5 * clean);
}

TEST(Quality, UfRenormalizesWhereANeuralFieldReports) {
  QualityParams p;
  BlockQuality q;
  q.sigma_tsdf_m = 0.02f;
  EXPECT_FLOAT_EQ(indicatorsOf(q, 0.08f, p)[kUf], 0.25f);  // no field: sigma_TSDF alone
  q.sigma_neural_m = 0.0f;
  EXPECT_FLOAT_EQ(indicatorsOf(q, 0.08f, p)[kUf], 0.125f);  // (0.5 * 0.25 + 0.5 * 0) / 1
}

TEST(Quality, NormalizationIsGuardedAndPriorityFollowsTheRule) {
  TsdfMap map(tsdfParams());
  const cv::Mat frame = depthImage([](int, int) { return kWallZ; });
  const FrameLevel f = frameLevel(frame);
  const ModelView m = modelView(frame);
  for (const char* rule : {"max", "sum"}) {
    SCOPED_TRACE(rule);
    QualityParams p = qualityParams();
    p.priority_rule = rule;
    p.lambda_cgn = 0.4;  // unequal weights: the max rule scales by the largest
    p.lambda_uf = 0.2;
    p.lambda_obg = 0.2;
    p.lambda_rm = 0.2;
    QualityMap quality(p);
    quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &m});
    const auto scores = quality.score(map.truncation());
    ASSERT_FALSE(scores.empty());
    for (const auto& s : scores) {
      for (int k = 0; k < kIndicatorCount; ++k) {
        EXPECT_TRUE(std::isfinite(s.normalized[k]));
        EXPECT_GE(s.normalized[k], 0.0f);
        EXPECT_LE(s.normalized[k], 1.0f);
      }
      // RM is 0 on every block: max = min, normalized to 0 (not NaN).
      EXPECT_EQ(s.normalized[kRm], 0.0f);
      const auto& n = s.normalized;
      const float expected = std::string(rule) == "sum" ? 0.4f * n[0] + 0.2f * (n[1] + n[2] + n[3])
                                                        : std::max({n[0], 0.5f * n[1], 0.5f * n[2], 0.5f * n[3]});
      EXPECT_NEAR(s.priority, expected, 1e-6f);
    }
    for (size_t i = 1; i < scores.size(); ++i) EXPECT_GE(scores[i - 1].priority, scores[i].priority);
  }
}

TEST(Quality, RoisAreConnectedChosenBlocksCappedInSizeWithMarginAndKeyframes) {
  TsdfMap map(tsdfParams());
  QualityParams p = qualityParams();
  p.top_fraction = 1.0;
  p.roi_max_extent_blocks = 4;
  p.roi_margin_voxels = 2;
  QualityMap quality(p);
  // Two keyframes; rendering misses two regions: x in [-1.12, -0.16) (6
  // blocks wide, cut into 4 + 2) and x in [0.48, 0.64) (one block column).
  for (uint32_t id = 0; id < 2; ++id) {
    const cv::Mat frame = depthImage([](int, int) { return kWallZ; });
    const cv::Mat model = depthImage([](int u, int) {
      const float x = pixelX(u, kWallZ);
      return (x >= -1.12f && x < -0.16f) || (x >= 0.48f && x < 0.64f) ? 0.0f : kWallZ;
    });
    const FrameLevel f = frameLevel(frame);
    const ModelView m = modelView(model);
    quality.update(map, {id, Eigen::Isometry3f::Identity(), &f, &m});
  }
  auto scores = quality.score(map.truncation());
  // Keep the blocks with a mismatch: the priority of the others is lower.
  std::vector<BlockScore> bad;
  for (const auto& s : scores) {
    if (s.raw[kRm] > 0.4f) bad.push_back(s);
  }
  ASSERT_FALSE(bad.empty());
  const auto rois = quality.selectRois(bad, map.voxelSize());
  const float bs = map.blockSize(), margin = 2 * map.voxelSize();
  size_t blocks = 0;
  int wide = 0, narrow = 0;
  for (const auto& roi : rois) {
    blocks += roi.blocks.size();
    BlockKey lo = roi.blocks[0], hi = roi.blocks[0];
    for (const auto& k : roi.blocks) {
      lo = lo.cwiseMin(k);
      hi = hi.cwiseMax(k);
    }
    EXPECT_LE((hi - lo).maxCoeff() + 1, 4);
    EXPECT_NEAR(roi.box_world.min().x(), lo.x() * bs - margin, 1e-5f);
    EXPECT_NEAR(roi.box_world.max().x(), (hi.x() + 1) * bs + margin, 1e-5f);
    EXPECT_EQ(roi.keyframes.size(), 2u);
    if (lo.x() >= 3) ++narrow;
    if (hi.x() <= -2) ++wide;
  }
  EXPECT_EQ(blocks, bad.size());
  EXPECT_GE(narrow, 1);
  EXPECT_GE(wide, 2);  // the 6-block-wide region is cut

  // The budget: a fraction of the scored blocks, capped.
  p.top_fraction = 0.1;
  p.max_blocks = 5;
  size_t chosen = 0;
  QualityMap q2(p);
  for (const auto& roi : q2.selectRois(scores, map.voxelSize())) chosen += roi.blocks.size();
  EXPECT_EQ(chosen, std::min<size_t>(5, static_cast<size_t>(std::ceil(0.1 * scores.size()))));
}

TEST(Quality, BlocksAndRoisKeepKeyframesSpreadInDirection) {
  // The wall seen from two cameras 1 m to either side (27 degrees off the
  // wall's center line), then from six nearly the same place in front. The
  // blocks at the wall's center keep the two side views (spread) or only
  // the six newest (recency).
  auto run = [](bool spread, std::vector<uint32_t>& block_ids, std::vector<uint32_t>& roi_ids, uint32_t& side_refs) {
    TsdfMap map(tsdfParams());
    QualityParams p = qualityParams();
    p.spread_keyframes = spread;
    p.top_fraction = 1.0;
    p.roi_max_keyframes = 3;
    QualityMap quality(p);
    const float xs[] = {-1.0f, 1.0f, 0.0f, 0.02f, 0.04f, 0.06f, 0.08f, 0.10f};
    const cv::Mat wall = depthImage([](int, int) { return kWallZ; });
    const FrameLevel f = frameLevel(wall);
    const ModelView m = modelView(wall);
    for (uint32_t id = 0; id < 8; ++id) {
      Eigen::Isometry3f T_world_cam = Eigen::Isometry3f::Identity();
      T_world_cam.translation().x() = xs[id];
      quality.update(map, {id, T_world_cam, &f, &m});
    }
    const BlockKey center(0, 0, 12);
    const BlockQuality* q = quality.find(center);
    ASSERT_NE(q, nullptr);
    ASSERT_EQ(q->keyframe_count, static_cast<uint32_t>(BlockQuality::kMaxKeyframes));
    block_ids.assign(q->keyframe_ids.begin(), q->keyframe_ids.end());
    std::sort(block_ids.begin(), block_ids.end());
    std::vector<BlockScore> one;
    for (const auto& s : quality.score(map.truncation())) {
      if (s.key == center) one.push_back(s);
    }
    ASSERT_EQ(one.size(), 1u);
    const auto rois = quality.selectRois(one, map.voxelSize());
    ASSERT_EQ(rois.size(), 1u);
    roi_ids = rois[0].keyframes;
    std::sort(roi_ids.begin(), roi_ids.end());
    side_refs = quality.keyframeReferences(0) + quality.keyframeReferences(1);
  };
  std::vector<uint32_t> blocks, roi;
  uint32_t side_refs = 0;
  run(true, blocks, roi, side_refs);
  EXPECT_TRUE(std::binary_search(blocks.begin(), blocks.end(), 0u));
  EXPECT_TRUE(std::binary_search(blocks.begin(), blocks.end(), 1u));
  EXPECT_TRUE(std::binary_search(blocks.begin(), blocks.end(), 7u));  // the newest always enters
  ASSERT_EQ(roi.size(), 3u);
  EXPECT_TRUE(std::binary_search(roi.begin(), roi.end(), 0u));  // both sides and one front view
  EXPECT_TRUE(std::binary_search(roi.begin(), roi.end(), 1u));
  const uint32_t spread_refs = side_refs;

  run(false, blocks, roi, side_refs);
  EXPECT_EQ(blocks, (std::vector<uint32_t>{2, 3, 4, 5, 6, 7}));
  EXPECT_EQ(roi.size(), 3u);
  EXPECT_EQ(roi.front(), 5u);
  // Only the wall's edges, which no other camera saw, still keep them.
  EXPECT_LT(side_refs, spread_refs);
  EXPECT_GT(side_refs, 0u);
}

TEST(Quality, BadInputsAreIgnoredNotFatal) {
  TsdfMap map(tsdfParams());
  QualityMap quality(qualityParams());
  const cv::Mat frame = depthImage([](int u, int) {
    if (u % 7 == 0) return std::numeric_limits<float>::quiet_NaN();
    if (u % 11 == 0) return std::numeric_limits<float>::infinity();
    return u % 5 == 0 ? 0.0f : kWallZ;
  });
  FrameLevel f = frameLevel(frame);
  const ModelView m = modelView(depthImage([](int, int) { return kWallZ; }));
  EXPECT_EQ(quality.update(map, {0, Eigen::Isometry3f::Identity(), nullptr, &m}).samples, 0u);
  ModelView small = m;
  small.depth = cv::Mat(10, 10, CV_32F, cv::Scalar(1.0f));
  EXPECT_EQ(quality.update(map, {0, Eigen::Isometry3f::Identity(), &f, &small}).samples, 0u);
  // On a fused wall, the finite pixels of the bad frame are scored and the
  // NaN, infinite and zero ones are not.
  const cv::Mat wall = depthImage([](int, int) { return kWallZ; });
  integrate(map, {wall, cv::Mat(), cv::Mat(), kCam, Eigen::Isometry3f::Identity()});
  size_t finite = 0;
  for (int v = 0; v < frame.rows; ++v) {
    for (int u = 0; u < frame.cols; ++u) finite += std::isfinite(frame.at<float>(v, u)) && frame.at<float>(v, u) > 0;
  }
  const size_t samples = quality.update(map, {1, Eigen::Isometry3f::Identity(), &f, &m}).samples;
  EXPECT_GT(samples, finite / 2);
  EXPECT_LE(samples, finite);
  const auto scores = quality.score(map.truncation());
  EXPECT_FALSE(scores.empty());
  for (const auto& s : scores) {
    for (float x : s.raw) EXPECT_TRUE(std::isfinite(x));
  }
}

}  // namespace
}  // namespace hxmap::alg
