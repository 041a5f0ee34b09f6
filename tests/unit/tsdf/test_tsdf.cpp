#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "hxmap/tsdf/raycast.hpp"

namespace hxmap::alg {
namespace {

const PinholeCamera kCam{300, 300, 159.5, 119.5, 320, 240, {0, 0, 0, 0, 0}};

TsdfParams params(double voxel) {
  TsdfParams p;
  p.voxel_size_m = voxel;
  p.truncation_m = 4 * voxel;
  return p;
}

DepthObservation observation(const drv::SyntheticScene& scene, const Eigen::Isometry3d& T_world_cam, bool noise,
                             int index) {
  drv::SyntheticParams sp;
  sp.noise = noise;
  const auto f = drv::renderFrame(scene, kCam, T_world_cam, sp, index);
  const auto pre = preprocessFrame({0, 0, f.rgb, f.depth}, kCam, PreprocessParams{});
  return {pre.depth_m, pre.rgb, pre.levels[pre.finest].confidence, kCam, T_world_cam.cast<float>()};
}

TEST(TsdfIntegration, OptimizedKernelAgreesWithReference) {
  const auto scene = drv::SyntheticScene::room();
  drv::SyntheticParams sp;
  const auto traj = drv::syntheticTrajectory(sp);
  TsdfMap fast(params(0.02)), ref(params(0.02));
  for (int i : {0, 15, 30}) {
    const auto obs = observation(scene, traj[i].T_world_cam, true, i);
    const auto a = integrate(fast, obs);
    const auto b = integrateReference(ref, obs);
    EXPECT_EQ(a.blocks_in_band, b.blocks_in_band);
  }
  ASSERT_EQ(fast.blockCount(), ref.blockCount());
  size_t voxels = 0, mismatched = 0;
  double worst_sdf = 0;
  for (size_t b = 0; b < fast.blockCount(); ++b) {
    ASSERT_EQ(fast.key(b), ref.key(b));
    for (int i = 0; i < kBlockVoxels; ++i) {
      const VoxelBlock &x = fast.block(b), &y = ref.block(b);
      if (x.geo[i].weight == 0 && y.geo[i].weight == 0) continue;
      ++voxels;
      // A voxel projecting exactly between two pixels may round to either
      // in float vs double: allow a handful of such voxels.
      if (std::abs(x.geo[i].weight - y.geo[i].weight) > 1e-5f || x.stats[i].updates != y.stats[i].updates) {
        ++mismatched;
        continue;
      }
      worst_sdf = std::max(worst_sdf, static_cast<double>(std::abs(x.geo[i].sdf_m - y.geo[i].sdf_m)));
    }
  }
  EXPECT_GT(voxels, 100000u);
  EXPECT_LT(mismatched, voxels / 10000 + 1) << "of " << voxels;
  EXPECT_LT(worst_sdf, 1e-5) << "m";
}

// A scene of one primitive seen from several sides; returns the map.
TsdfMap mapOf(const drv::Primitive& prim, double voxel, const Eigen::Vector3d& center, double distance) {
  drv::SyntheticScene scene;
  scene.mutablePrimitives().push_back(prim);
  TsdfMap map(params(voxel));
  for (int k = 0; k < 8; ++k) {
    const double a = 2 * M_PI * k / 8;
    const Eigen::Vector3d eye = center + distance * Eigen::Vector3d(std::cos(a), std::sin(a), 0.6).normalized();
    const Eigen::Vector3d f = (center - eye).normalized();
    const Eigen::Vector3d r = f.cross(Eigen::Vector3d::UnitZ()).normalized();
    Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
    T_world_cam.linear().col(0) = r;
    T_world_cam.linear().col(1) = f.cross(r);
    T_world_cam.linear().col(2) = f;
    T_world_cam.translation() = eye;
    integrate(map, observation(scene, T_world_cam, false, k));
  }
  return map;
}

// Re-integration (pose feedback): integrating a frame at a wrong pose,
// taking it back out and integrating it at the right one leaves the map a
// map fused at the right poses would be (below the weight cap).
TEST(TsdfIntegration, DeintegrationUndoesAnObservation) {
  const auto scene = drv::SyntheticScene::room();
  drv::SyntheticParams sp;
  const auto traj = drv::syntheticTrajectory(sp);
  TsdfMap fixed(params(0.02)), expected(params(0.02));
  const auto a = observation(scene, traj[0].T_world_cam, true, 0);
  const auto b = observation(scene, traj[10].T_world_cam, true, 10);
  auto wrong = observation(scene, traj[20].T_world_cam, true, 20);
  const auto right = wrong;
  wrong.T_world_cam = right.T_world_cam * Eigen::Translation3f(0.03f, -0.02f, 0.01f) *
                      Eigen::AngleAxisf(0.02f, Eigen::Vector3f::UnitY());
  integrate(expected, a);
  integrate(expected, right);
  integrate(expected, b);
  integrate(fixed, a);
  integrate(fixed, wrong);
  integrate(fixed, b);
  const auto removed = deintegrate(fixed, wrong);
  EXPECT_GT(removed.voxels_updated, 10000u);
  EXPECT_EQ(removed.blocks_allocated, 0u);  // every block it touches exists already
  integrate(fixed, right);
  size_t voxels = 0, weight_off = 0, sdf_off = 0, color_off = 0, near = 0;
  for (size_t i = 0; i < expected.blockCount(); ++i) {
    const int32_t j = fixed.find(expected.key(i));
    ASSERT_GE(j, 0);
    const VoxelBlock &x = fixed.block(j), &y = expected.block(i);
    for (int v = 0; v < kBlockVoxels; ++v) {
      if (y.geo[v].weight == 0) continue;
      ++voxels;
      weight_off += std::abs(x.geo[v].weight - y.geo[v].weight) > 1e-3f;
      // Fusion order differs (b after the right pose vs before it): float
      // rounding only, far below a millimeter.
      sdf_off += std::abs(x.geo[v].sdf_m - y.geo[v].sdf_m) > 1e-4f;
      // Color is a running average over in-band updates only, so it
      // depends on order more: compared where the surface is.
      if (std::abs(y.geo[v].sdf_m) < 0.02f) {
        ++near;
        color_off += std::abs(x.color[v].r - y.color[v].r) > 8;
      }
    }
  }
  EXPECT_GT(voxels, 50000u);
  EXPECT_LE(weight_off, voxels / 1000) << voxels;
  EXPECT_LE(sdf_off, voxels / 1000) << voxels;
  EXPECT_LE(color_off, near / 50) << near;  // measured 1.1%
  // Removing the only observation leaves voxels unobserved.
  TsdfMap single(params(0.02));
  integrate(single, a);
  deintegrate(single, a);
  for (size_t i = 0; i < single.blockCount(); ++i) {
    for (int v = 0; v < kBlockVoxels; ++v) ASSERT_EQ(single.block(i).geo[v].weight, 0.0f);
  }
}

// A wall seen first from farther back (the voxels in front of that
// surface take free-space clamps: weight, no color), then at the voxels'
// own depth: the surface there has the wall's color, not a blend with the
// black a voxel starts from.
TEST(TsdfIntegration, ColorOfASurfaceFirstReachedByFreeSpaceIsNotDarkened) {
  TsdfMap map(params(0.02));
  auto wall = [&](float depth, uint8_t r, uint8_t g, uint8_t b) {
    DepthObservation o;
    o.depth_m = cv::Mat(kCam.height, kCam.width, CV_32F, cv::Scalar(depth));
    o.rgb = cv::Mat(kCam.height, kCam.width, CV_8UC3, cv::Scalar(r, g, b));
    o.camera = kCam;
    return o;
  };
  integrate(map, wall(1.10f, 30, 30, 30));  // the surface behind: clamps at z = 1.0
  integrate(map, wall(1.00f, 200, 100, 50));
  size_t surface = 0, off = 0;
  for (size_t b = 0; b < map.blockCount(); ++b) {
    const VoxelBlock& blk = map.block(b);
    for (int i = 0; i < kBlockVoxels; ++i) {
      const float z = (static_cast<float>(map.key(b).z() * kBlockSide + i / (kBlockSide * kBlockSide)) + 0.5f) * 0.02f;
      if (blk.geo[i].weight == 0 || std::abs(z - 1.0f) > 0.015f) continue;
      ++surface;
      off +=
          std::abs(blk.color[i].r - 200) > 2 || std::abs(blk.color[i].g - 100) > 2 || std::abs(blk.color[i].b - 50) > 2;
    }
  }
  EXPECT_GT(surface, 1000u);
  EXPECT_EQ(off, 0u) << "of " << surface;
  // Taking the only colored observation back out leaves no color.
  deintegrate(map, wall(1.00f, 200, 100, 50));
  for (size_t b = 0; b < map.blockCount(); ++b) {
    const VoxelBlock& blk = map.block(b);
    for (int i = 0; i < kBlockVoxels; ++i) {
      if (blk.stats[i].updates == 0) {
        ASSERT_EQ(blk.color[i].r, 0) << "block " << b << " voxel " << i;
      }
    }
  }
}

TEST(TsdfIntegration, SphereRecoveredWithinHalfAVoxel) {
  for (double voxel : {0.01, 0.02}) {
    drv::Primitive sphere;
    sphere.kind = drv::Primitive::Kind::kSphere;
    sphere.a = Eigen::Vector3f(0.1f, -0.2f, 0.3f);
    sphere.radius = 0.25f;
    const TsdfMap map = mapOf(sphere, voxel, sphere.a.cast<double>(), 1.2);
    const TriangleMesh mesh = extractMesh(map, MeshParams{});
    ASSERT_GT(mesh.vertices.size(), 1000u);
    double worst = 0, sum = 0;
    for (const auto& v : mesh.vertices) {
      const double e = std::abs((v - sphere.a).norm() - sphere.radius);
      worst = std::max(worst, e);
      sum += e;
    }
    EXPECT_LT(sum / mesh.vertices.size(), 0.1 * voxel) << "mean error at voxel " << voxel;
    EXPECT_LT(worst, 0.5 * voxel) << "worst error at voxel " << voxel;
  }
}

TEST(TsdfIntegration, PlaneRecoveredWithinHalfAVoxelByRaycast) {
  drv::Primitive floor;  // a large slab, top face at z = 0.013 (off the voxel grid)
  floor.kind = drv::Primitive::Kind::kBox;
  floor.a = Eigen::Vector3f(0, 0, -0.487f);
  floor.b = Eigen::Vector3f(3, 3, 0.5f);
  const double voxel = 0.02;
  const TsdfMap map = mapOf(floor, voxel, {0, 0, 0.013}, 1.5);
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  T_world_cam.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();  // looking down
  T_world_cam.translation() = Eigen::Vector3d(0, 0, 1.2);
  const ModelView view = raycast(map, kCam, T_world_cam.cast<float>(), RaycastParams{});
  ASSERT_GT(view.valid_pixels, kCam.width * kCam.height / 2);
  double worst = 0;
  size_t normals = 0, tilted = 0;  // tilted: more than 8.1 degrees off
  for (int v = 0; v < kCam.height; ++v) {
    for (int u = 0; u < kCam.width; ++u) {
      if (view.depth.at<float>(v, u) <= 0) continue;
      worst = std::max(worst, std::abs(static_cast<double>(view.vertex_world.at<cv::Vec3f>(v, u)[2]) - 0.013));
      const cv::Vec3f n = view.normal_world.at<cv::Vec3f>(v, u);
      if (n[2] != 0) {
        ++normals;
        tilted += n[2] < 0.99f;
        EXPECT_GT(n[2], 0.98f) << "pixel " << u << "," << v << ": more than 11.5 degrees off";
      }
    }
  }
  EXPECT_LT(worst, 0.5 * voxel);
  // Fusion reads every second pixel here (integration_level auto): a few
  // dozen normals where the views' footprints meet tilt by up to ~10 degrees.
  EXPECT_LT(tilted, normals / 500) << "of " << normals;
}

TEST(TsdfMap, AllocatesOnlyTheBandAndAccountsMemory) {
  drv::Primitive sphere;
  sphere.kind = drv::Primitive::Kind::kSphere;
  sphere.radius = 0.3f;
  const TsdfMap map = mapOf(sphere, 0.02, Eigen::Vector3d::Zero(), 1.2);
  const float band = map.truncation() + map.blockSize() * std::sqrt(3.0f);
  for (size_t b = 0; b < map.blockCount(); ++b) {
    const Eigen::Vector3f center = (map.key(b).cast<float>() + Eigen::Vector3f::Constant(0.5f)) * map.blockSize();
    EXPECT_LT(std::abs(center.norm() - sphere.radius), band);
  }
  const MapMemory mem = map.memory();
  EXPECT_EQ(mem.blocks, map.blockCount());
  EXPECT_GE(mem.bytes, map.blockCount() * sizeof(VoxelBlock));
  // Update statistics are kept for the UF indicator.
  size_t with_stats = 0;
  for (size_t b = 0; b < map.blockCount(); ++b) {
    for (const auto& st : map.block(b).stats) with_stats += st.updates > 1;
  }
  EXPECT_GT(with_stats, 1000u);
}

TEST(TsdfMap, BlocksNeverMoveAndCopiesAreDeep) {
  TsdfMap map(params(0.02));
  const int32_t first = map.findOrAllocate(BlockKey(0, 0, 0));
  VoxelBlock* const address = &map.block(static_cast<size_t>(first));
  address->geo[5].sdf_m = 0.03f;
  for (int i = 1; i < 300; ++i) map.findOrAllocate(BlockKey(i, -i, 2 * i));  // 19 chunks
  EXPECT_EQ(&map.block(static_cast<size_t>(first)), address);
  EXPECT_EQ(map.blockCount(), 300u);
  // Memory counts whole chunks: at most one partly used.
  EXPECT_GE(map.memory().bytes, 300 * sizeof(VoxelBlock));
  EXPECT_LT(map.memory().bytes, 316 * sizeof(VoxelBlock) + (1u << 20));

  TsdfMap copy = map;
  address->geo[5].sdf_m = -0.01f;
  EXPECT_FLOAT_EQ(copy.block(static_cast<size_t>(copy.find(BlockKey(0, 0, 0)))).geo[5].sdf_m, 0.03f);
  EXPECT_EQ(copy.blockCount(), 300u);
  EXPECT_EQ(copy.find(BlockKey(299, -299, 598)), map.find(BlockKey(299, -299, 598)));
  copy = map;
  EXPECT_FLOAT_EQ(copy.block(static_cast<size_t>(copy.find(BlockKey(0, 0, 0)))).geo[5].sdf_m, -0.01f);
}

// A checkpoint's snapshot: the map as it was when taken, whatever the map
// is written afterwards; voxel memory shared but for the chunks written
// since, which each side copies before its first write into them.
TEST(TsdfMap, ASnapshotKeepsItsInstantAndOnlyWrittenChunksAreCopied) {
  const auto scene = drv::SyntheticScene::room();
  drv::SyntheticParams sp;
  const auto traj = drv::syntheticTrajectory(sp);
  TsdfMap map(params(0.01));
  for (int k = 0; k < 60; k += 6) integrate(map, observation(scene, traj[static_cast<size_t>(k)].T_world_cam, true, k));
  const size_t chunks = (map.blockCount() + TsdfMap::chunkBlocks() - 1) / TsdfMap::chunkBlocks();
  ASSERT_GT(chunks, 50u);
  const TsdfMap deep = map;
  TsdfMap snap = map.snapshot();
  ASSERT_EQ(snap.blockCount(), map.blockCount());
  const auto sameVoxels = [](const VoxelBlock& a, const VoxelBlock& b) {
    return std::memcmp(a.geo, b.geo, sizeof(a.geo)) == 0 && std::memcmp(a.color, b.color, sizeof(a.color)) == 0 &&
           std::memcmp(a.stats, b.stats, sizeof(a.stats)) == 0;
  };
  // Shared, not copied.
  const TsdfMap& const_map = map;
  const TsdfMap& const_snap = snap;
  EXPECT_EQ(&const_snap.block(0), &const_map.block(0));
  EXPECT_EQ(map.chunksCopiedOnWrite(), 0u);

  // One more frame from elsewhere along the path: the map changes, the
  // snapshot does not, and only chunks that frame wrote were copied.
  const DepthObservation later = observation(scene, traj[140].T_world_cam, true, 140);
  const IntegrationStats st = integrate(map, later);
  ASSERT_GT(st.voxels_updated, 10000u);
  const uint64_t copied = map.chunksCopiedOnWrite();
  EXPECT_GT(copied, 0u);
  EXPECT_LT(copied, chunks);
  size_t changed = 0;
  for (size_t b = 0; b < deep.blockCount(); ++b) {
    ASSERT_EQ(snap.key(b), deep.key(b));
    ASSERT_TRUE(sameVoxels(const_snap.block(b), deep.block(b))) << "block " << b;
    changed += !sameVoxels(const_map.block(b), deep.block(b));
  }
  EXPECT_GT(changed, 10u);
  // The same blocks written again: each chunk was copied once.
  integrate(map, later);
  EXPECT_EQ(map.chunksCopiedOnWrite(), copied);

  // A write into the snapshot stays in the snapshot.
  const int32_t far = static_cast<int32_t>(deep.blockCount() - 1);
  const float before = const_map.block(static_cast<size_t>(far)).geo[3].sdf_m;
  snap.block(static_cast<size_t>(far)).geo[3].sdf_m = before + 1.0f;
  EXPECT_EQ(const_map.block(static_cast<size_t>(far)).geo[3].sdf_m, before);
  EXPECT_EQ(snap.chunksCopiedOnWrite(), 1u);

  // Once every snapshot is gone the map writes in place: a view the
  // first frames had fused copies nothing.
  TsdfMap copy(params(0.01));
  copy = snap;  // a (deep) copy of a snapshot holds nothing
  snap = TsdfMap(params(0.01));
  { const TsdfMap gone = map.snapshot(); }
  integrate(map, observation(scene, traj[120].T_world_cam, true, 120));
  EXPECT_EQ(map.chunksCopiedOnWrite(), copied) << "no snapshot was alive";

  // Blocks moved out and the map cleared leave a snapshot as it was.
  const TsdfMap deep2 = map;
  const TsdfMap snap2 = map.snapshot();
  map.removeBlocks({0, 1, 2, far});
  map.clear();
  ASSERT_EQ(snap2.blockCount(), deep2.blockCount());
  for (size_t b = 0; b < deep2.blockCount(); ++b) ASSERT_TRUE(sameVoxels(snap2.block(b), deep2.block(b)));
}

TEST(TsdfMap, AssignedBlocksReuseMemoryAndLeaveNothingStale) {
  // A copy of the blocks in a box, made again into the same map: the same
  // blocks as copyBlocks, no new memory, and a block allocated later in a
  // slot an earlier copy used starts empty.
  TsdfMap map(params(0.02));
  for (int i = 0; i < 40; ++i) {
    VoxelBlock& b = map.block(static_cast<size_t>(map.findOrAllocate(BlockKey(i, 0, 0))));
    b.geo[7].sdf_m = 0.001f * static_cast<float>(i);
    b.geo[7].weight = 2.0f;
  }
  const float bs = map.blockSize();
  const Eigen::AlignedBox3f all(Eigen::Vector3f(0.5f * bs, 0, 0), Eigen::Vector3f(39.5f * bs, 0.5f * bs, 0.5f * bs));
  const Eigen::AlignedBox3f some(Eigen::Vector3f(10.5f * bs, 0, 0), Eigen::Vector3f(19.5f * bs, 0.5f * bs, 0.5f * bs));
  TsdfMap copy(params(0.02));
  copy.assignBlocks(map, all);
  EXPECT_EQ(copy.blockCount(), 40u);
  const size_t bytes = copy.memory().bytes;
  copy.assignBlocks(map, some);
  const TsdfMap expected = copyBlocks(map, some);
  ASSERT_EQ(copy.blockCount(), expected.blockCount());
  EXPECT_EQ(copy.blockCount(), 10u);
  for (int i = 10; i < 20; ++i) {
    const int32_t b = copy.find(BlockKey(i, 0, 0));
    ASSERT_GE(b, 0) << i;
    EXPECT_FLOAT_EQ(copy.block(static_cast<size_t>(b)).geo[7].sdf_m, 0.001f * static_cast<float>(i));
  }
  EXPECT_LT(copy.find(BlockKey(5, 0, 0)), 0);
  EXPECT_LE(copy.memory().bytes, bytes) << "no new chunks";
  EXPECT_GE(copy.memory().bytes, 40 * sizeof(VoxelBlock)) << "the chunks stay";
  // Slot 10 held block (10, 0, 0)'s voxels in the first copy's layout; a
  // new block there starts empty.
  const int32_t fresh = copy.findOrAllocate(BlockKey(100, 0, 0));
  EXPECT_EQ(copy.block(static_cast<size_t>(fresh)).geo[7].weight, 0.0f);
  EXPECT_EQ(copy.block(static_cast<size_t>(fresh)).geo[7].sdf_m, VoxelBlock{}.geo[7].sdf_m);

  // An empty box copies nothing; a huge one (more cells than blocks) every block.
  copy.assignBlocks(map, Eigen::AlignedBox3f());
  EXPECT_EQ(copy.blockCount(), 0u);
  const float inf = std::numeric_limits<float>::infinity();
  copy.assignBlocks(map, Eigen::AlignedBox3f(Eigen::Vector3f::Constant(-1e4f), Eigen::Vector3f::Constant(1e4f)));
  EXPECT_EQ(copy.blockCount(), 40u);
  copy.assignBlocks(map, Eigen::AlignedBox3f(Eigen::Vector3f::Constant(-inf), Eigen::Vector3f::Constant(inf)));
  EXPECT_EQ(copy.blockCount(), 0u) << "not finite: nothing";
}

TEST(TsdfPatch, FusesLikeAnObservationAndRejectsBadValues) {
  TsdfMap map(params(0.02));  // mu 8 cm, max weight 64
  TsdfPatch patch;
  patch.entries.push_back({Eigen::Vector3i(3, -2, 9), 0.01f, 2.0f});  // new block
  patch.entries.push_back({Eigen::Vector3i(3, -2, 9), 0.04f, 2.0f});  // same voxel again
  patch.entries.push_back({Eigen::Vector3i(-9, 0, 0), 0.5f, 1.0f});   // beyond the band: clamped
  patch.entries.push_back({Eigen::Vector3i(0, 0, 0), std::nanf(""), 1.0f});
  patch.entries.push_back({Eigen::Vector3i(0, 0, 0), 0.01f, 0.0f});
  const PatchStats st = applyPatch(map, patch);
  EXPECT_EQ(st.applied, 3u);
  EXPECT_EQ(st.rejected, 2u);
  EXPECT_EQ(st.blocks_allocated, 2u);
  Voxel v;
  ASSERT_TRUE(map.voxel(Eigen::Vector3i(3, -2, 9), v));
  EXPECT_NEAR(v.sdf_m, 0.025f, 1e-6f) << "weighted mean of the two corrections";
  EXPECT_NEAR(v.weight, 4.0f, 1e-6f);
  ASSERT_TRUE(map.voxel(Eigen::Vector3i(-9, 0, 0), v));
  EXPECT_NEAR(v.sdf_m, 0.08f, 1e-6f);
  EXPECT_FALSE(map.voxel(Eigen::Vector3i(0, 0, 0), v)) << "rejected entries allocate nothing";
}

TEST(TsdfPatch, AVoxelSeenThroughTakesNoObservationFromBehindASurface) {
  // A wall at z = 1 m fused once; voxels up to mu behind it are inside.
  // Refinement writes two of them (z = 1.05 m) outside, one flagged seen
  // through. Fusing the wall again moves the unflagged one back inside and
  // leaves the flagged one; a flagged voxel at the surface (1.01 m) is
  // fused as usual and loses the flag. The reference kernel and
  // de-integration treat the flag alike.
  for (const bool reference : {false, true}) {
    TsdfMap map(params(0.02));
    DepthObservation wall{cv::Mat(kCam.height, kCam.width, CV_32F, cv::Scalar(1.0f)), cv::Mat(), cv::Mat(), kCam,
                          Eigen::Isometry3f::Identity()};
    auto fuse = [&]() { return reference ? integrateReference(map, wall) : integrate(map, wall); };
    fuse();
    const Eigen::Vector3i behind(0, 0, 52), control(1, 0, 52), at_surface(0, 1, 50);
    Voxel v;
    ASSERT_TRUE(map.voxel(behind, v));
    ASSERT_NEAR(v.sdf_m, -0.05f, 1e-4f);
    TsdfPatch patch;
    patch.entries.push_back({behind, 0.08f, 1000.0f, {0, 0, 0}, false, true});
    patch.entries.push_back({control, 0.08f, 1000.0f, {0, 0, 0}, false, false});
    patch.entries.push_back({at_surface, 0.08f, 1000.0f, {0, 0, 0}, false, true});
    const PatchStats st = applyPatch(map, patch);
    EXPECT_EQ(st.seen_through, 2u);
    ASSERT_TRUE(map.voxel(behind, v));
    const float written = v.sdf_m;
    EXPECT_GT(written, 0.07f);
    EXPECT_TRUE(v.color.flags & kVoxelSeenThrough);
    for (int i = 0; i < 5; ++i) fuse();
    ASSERT_TRUE(map.voxel(behind, v));
    EXPECT_FLOAT_EQ(v.sdf_m, written) << (reference ? "reference" : "optimized");
    EXPECT_TRUE(v.color.flags & kVoxelSeenThrough);
    ASSERT_TRUE(map.voxel(control, v));
    EXPECT_LT(v.sdf_m, written - 0.005f);
    ASSERT_TRUE(map.voxel(at_surface, v));
    EXPECT_FALSE(v.color.flags & kVoxelSeenThrough);
    if (!reference) {
      deintegrate(map, wall);
      ASSERT_TRUE(map.voxel(behind, v));
      EXPECT_FLOAT_EQ(v.sdf_m, written);
    }
    // A later correction that puts the voxel inside clears the flag.
    TsdfPatch inside;
    inside.entries.push_back({behind, -0.08f, 1e5f, {0, 0, 0}, false, true});
    applyPatch(map, inside);
    ASSERT_TRUE(map.voxel(behind, v));
    EXPECT_LT(v.sdf_m, 0.0f);
    EXPECT_FALSE(v.color.flags & kVoxelSeenThrough);
  }
}

}  // namespace
}  // namespace hxmap::alg
