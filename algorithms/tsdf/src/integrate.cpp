#include "hxmap/tsdf/integrate.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

int integrationLevel(const TsdfMap& map, const PinholeCamera& camera) {
  if (map.params().integration_level >= 0) return std::min(map.params().integration_level, 3);
  // Auto: half resolution where a voxel at max_integration_depth_m still
  // spans half a pixel there (fx 525, 4 m: 2 cm -> 1.3 px, 1 cm -> 0.66 px).
  // Measured on the synthetic orbit/sweep at 1 cm voxels, level 1 vs 0: mesh
  // F1@1cm 95.0/96.5% vs 94.8/96.4%, ATE unchanged, fusion 1.6x faster.
  const double px = 0.5 * std::min(camera.fx, camera.fy) * map.voxelSize() / map.params().max_integration_depth_m;
  return px >= 0.5 ? 1 : 0;
}

int allocationStride(const TsdfMap& map, double focal_px) {
  if (map.params().allocation_stride_px > 0) return map.params().allocation_stride_px;
  // Auto: the pixels a block spans at max_integration_depth_m over 2.5 (at
  // integration level 1, fx 525: 2 cm voxels -> 4, 1 cm -> 2). Measured on
  // the synthetic orbit at 2 cm: stride 3 and 4 give the same mesh, 5 loses
  // 0.2% recall.
  const double span_px = focal_px * map.blockSize() / map.params().max_integration_depth_m;
  return std::clamp(static_cast<int>(span_px / 2.5), 1, 16);
}

namespace {

// The observation as fusion reads it: every 2^level-th pixel in both
// directions, depth, confidence and color side by side (one cache line per
// lookup instead of three), depth 0 where the pixel is not to be integrated.
// DESIGN:
// fusion is bound by these scattered reads, not by arithmetic; at 2 cm
// voxels a voxel covers 2.6 px or more up to 4 m, so reading every second
// pixel (a quarter of the memory, which then stays in L2) loses nothing
// (measured 2.1 -> 1.2 ms per frame on the TUM slice).
struct PackedDepth {
  struct Pixel {
    float depth_m;
    float confidence;
    uint8_t rgb[4];  // the fourth byte is padding
  };
  int level = 0, width = 0, height = 0;
  std::unique_ptr<Pixel[]> pixels;  // every pixel written by packObservation (no zero fill first)
  // Projection onto the packed grid: sample (u, v) is pixel (u, v) << level.
  float fx = 0, fy = 0, cx = 0, cy = 0;
  const Pixel& at(int u, int v) const { return pixels[static_cast<size_t>(v) * width + u]; }
  const Pixel* data() const { return pixels.get(); }
};

// Confidence may come at a pyramid level of the depth: pixel (u, v) reads
// (u >> shift, v >> shift).
int confidenceShift(const DepthObservation& obs) {
  int shift = 0;
  while (shift < 4 && (obs.confidence.cols << shift) < obs.depth_m.cols) ++shift;
  return shift;
}

PackedDepth packObservation(const TsdfMap& map, const DepthObservation& obs) {
  PackedDepth out;
  out.level = integrationLevel(map, obs.camera);
  const int step = 1 << out.level;
  const float scale = 1.0f / static_cast<float>(step);
  out.width = (obs.depth_m.cols + step - 1) / step;
  out.height = (obs.depth_m.rows + step - 1) / step;
  out.fx = static_cast<float>(obs.camera.fx) * scale;
  out.fy = static_cast<float>(obs.camera.fy) * scale;
  out.cx = static_cast<float>(obs.camera.cx) * scale;
  out.cy = static_cast<float>(obs.camera.cy) * scale;
  out.pixels.reset(new PackedDepth::Pixel[static_cast<size_t>(out.width) * out.height]);
  const float max_depth = static_cast<float>(map.params().max_integration_depth_m);
  const float min_conf = static_cast<float>(map.params().min_confidence);
  const bool has_conf = !obs.confidence.empty(), has_rgb = !obs.rgb.empty();
  const int cs = confidenceShift(obs);
  for (int v = 0; v < out.height; ++v) {
    const float* drow = obs.depth_m.ptr<float>(v * step);
    const float* crow = has_conf ? obs.confidence.ptr<float>((v * step) >> cs) : nullptr;
    const uint8_t* rgb = has_rgb ? obs.rgb.ptr<uint8_t>(v * step) : nullptr;
    PackedDepth::Pixel* o = &out.pixels[static_cast<size_t>(v) * out.width];
    for (int u = 0; u < out.width; ++u) {
      const float d = drow[u * step];
      const float c = crow ? crow[(u * step) >> cs] : 1.0f;
      const bool ok = d > 0.0f && d <= max_depth && c >= min_conf && c > 0.0f;
      o[u].depth_m = ok ? d : 0.0f;
      o[u].confidence = ok ? c : 0.0f;
      if (rgb) {
        const uint8_t* k = rgb + 3 * u * step;
        o[u].rgb[0] = k[0];
        o[u].rgb[1] = k[1];
        o[u].rgb[2] = k[2];
      } else {
        o[u].rgb[0] = o[u].rgb[1] = o[u].rgb[2] = 0;
      }
      o[u].rgb[3] = 0;
    }
  }
  return out;
}

std::vector<int32_t> allocateBand(TsdfMap& map, const PackedDepth& img, const Eigen::Isometry3f& T_world_cam,
                                  size_t* newly_allocated) {
  const float mu = map.truncation();
  const int stride = allocationStride(map, std::min(img.fx, img.fy));
  const size_t before = map.blockCount();
  std::vector<int32_t> touched;
  std::vector<uint8_t> mark(map.blockCount(), 0);
  // DESIGN: neighbouring samples, in a row and from one row to the next,
  // mostly fall in blocks touched moments ago. A small direct-mapped set of
  // the keys touched in this call answers those without the map's hash
  // table (a third of integration's time went to these lookups when only
  // the last key was remembered).
  constexpr int kRecent = 256;
  std::array<BlockKey, kRecent> recent;
  recent.fill(BlockKey(std::numeric_limits<int>::min(), 0, 0));
  auto touch = [&](const Eigen::Vector3f& q) {  // q in block units
    const BlockKey key(floorToInt(q.x()), floorToInt(q.y()), floorToInt(q.z()));
    const uint32_t h = static_cast<uint32_t>(key.x()) * 73856093u ^ static_cast<uint32_t>(key.y()) * 19349663u ^
                       static_cast<uint32_t>(key.z()) * 83492791u;  // unsigned: wraps, no overflow
    BlockKey& slot = recent[h & (kRecent - 1)];
    if (slot == key) return;  // touched already
    slot = key;
    const int32_t b = map.findOrAllocate(key);
    if (static_cast<size_t>(b) >= mark.size()) mark.resize(b + 1, 0);
    if (!mark[b]) {
      mark[b] = 1;
      touched.push_back(b);
    }
  };
  // Work in block units: q = (R p_cam + t) / block_size, the pixel's ray
  // direction (z = 1) built incrementally along the row. Each pixel's band
  // [z - mu, z + mu] is sampled every half block.
  const float inv_bs = 1.0f / map.blockSize();
  const Eigen::Matrix3f R = T_world_cam.linear() * inv_bs;
  const Eigen::Vector3f t = T_world_cam.translation() * inv_bs;
  const float inv_fx = 1.0f / img.fx, inv_fy = 1.0f / img.fy;
  for (int v = stride / 2; v < img.height; v += stride) {
    const Eigen::Vector3f row_dir = R.col(1) * ((static_cast<float>(v) - img.cy) * inv_fy) + R.col(2);
    for (int u = stride / 2; u < img.width; u += stride) {
      const float z = img.at(u, v).depth_m;
      if (!(z > 0)) continue;
      const Eigen::Vector3f dir = row_dir + R.col(0) * ((static_cast<float>(u) - img.cx) * inv_fx);
      const float z0 = std::max(0.01f, z - mu), z1 = z + mu;
      const Eigen::Vector3f a = t + dir * z0, d = dir * (z1 - z0);
      const int n = std::max(1, static_cast<int>(2.0f * d.norm()) + 1);  // half-block steps
      const float inv_n = 1.0f / static_cast<float>(n);
      for (int k = 0; k <= n; ++k) touch(a + d * (static_cast<float>(k) * inv_n));
    }
  }
  if (newly_allocated) *newly_allocated = map.blockCount() - before;
  return touched;
}

}  // namespace

std::vector<int32_t> allocateBand(TsdfMap& map, const DepthObservation& obs, size_t* newly_allocated) {
  return allocateBand(map, packObservation(map, obs), obs.T_world_cam, newly_allocated);
}

namespace {

// Weighted running averages: x += a (obs - x) with a = w / (W + w), the
// weight then capped. Color and update statistics only from observations
// inside the band (tsdf < mu), not from free-space clamps.
HXMAP_INLINE_IN_CLONES float fuseGeometry(VoxelBlock& blk, int i, float tsdf, float w, float max_w) {
  const float new_w = blk.geo[i].weight + w;
  const float a = w / std::max(new_w, 1e-20f);  // 0 where w = 0
  blk.geo[i].sdf_m += a * (tsdf - blk.geo[i].sdf_m);
  blk.geo[i].weight = std::min(new_w, max_w);
  return a;
}

HXMAP_INLINE_IN_CLONES void fuseAppearance(VoxelBlock& blk, int i, float tsdf, float a, const uint8_t* rgb) {
  VoxelStats& st = blk.stats[i];
  if (rgb) {  // in [0, 255]: +0.5 and truncation round to nearest (no libm call)
    // DESIGN: the first in-band observation sets the color. The weight a
    // voxel already holds may come from free-space clamps alone, which
    // carry no color: blending with the black a voxel starts from darkened
    // the surface wherever the band of earlier frames reached it first.
    const float ac = st.updates == 0 ? 1.0f : a;
    VoxelColor& k = blk.color[i];
    k.r = static_cast<uint8_t>(k.r + ac * (static_cast<float>(rgb[0]) - k.r) + 0.5f);
    k.g = static_cast<uint8_t>(k.g + ac * (static_cast<float>(rgb[1]) - k.g) + 0.5f);
    k.b = static_cast<uint8_t>(k.b + ac * (static_cast<float>(rgb[2]) - k.b) + 0.5f);
  }
  ++st.updates;
  const float delta = tsdf - st.mean_m;
  st.mean_m += delta / static_cast<float>(st.updates);
  st.m2 += delta * (tsdf - st.mean_m);
}

// The inverse of fuseGeometry + fuseAppearance for an observation fused
// earlier (de-integration): the running averages with the observation taken
// out. Exact while the weight was below the cap; at the cap the average is
// treated as if it held max_weight of evidence (what fusion keeps). A voxel
// left without weight returns to unobserved.
inline void removeObservation(VoxelBlock& blk, int i, float tsdf, float w, float mu, const uint8_t* rgb) {
  VoxelGeometry& g = blk.geo[i];
  const float remaining = g.weight - w;
  if (!(remaining > 1e-4f)) {
    g = VoxelGeometry{};
    blk.color[i] = VoxelColor{};
    blk.stats[i] = VoxelStats{};
    return;
  }
  const float inv = 1.0f / remaining;
  g.sdf_m = std::clamp((g.sdf_m * g.weight - tsdf * w) * inv, -mu, mu);
  if (tsdf >= mu) {
    g.weight = remaining;
    return;
  }
  VoxelStats& st = blk.stats[i];
  if (rgb && st.updates <= 1) {  // the only in-band observation goes: no color left
    VoxelColor& k = blk.color[i];
    k.r = k.g = k.b = 0;
  } else if (rgb) {
    VoxelColor& k = blk.color[i];
    auto un = [&](uint8_t c, uint8_t o) {
      const float v = (static_cast<float>(c) * g.weight - static_cast<float>(o) * w) * inv;
      return static_cast<uint8_t>(std::clamp(v, 0.0f, 255.0f) + 0.5f);
    };
    k.r = un(k.r, rgb[0]);
    k.g = un(k.g, rgb[1]);
    k.b = un(k.b, rgb[2]);
  }
  g.weight = remaining;
  if (st.updates <= 1) {
    st = VoxelStats{};
    return;
  }
  // Welford in reverse.
  const float n = static_cast<float>(st.updates);
  const float mean_before = (st.mean_m * n - tsdf) / (n - 1.0f);
  st.m2 = std::max(0.0f, st.m2 - (tsdf - mean_before) * (tsdf - st.mean_m));
  st.mean_m = mean_before;
  --st.updates;
}

// What a row of voxels needs to find its pixels.
struct RowLookup {
  Eigen::Vector3f dx, dy, dz;  // one voxel along x, y, z, in the camera frame
  float fx, fy, cx, cy, Wf, Hf, mu;
  float voxel;                       // size
  const PackedDepth::Pixel* pixels;  // a plain pointer: the compiler cannot
  int width;                         // tell a vector's own apart from voxels
};

// A row of 8 voxels starting at p0 (camera frame): truncated SDF, weight
// (0: not updated) and pixel color of each; false when none is updated.
// Nearest sample: floor(x + 0.5) by truncation once x + 0.5 >= 0. Voxels
// behind the camera give inf/NaN in the projection, which every test
// rejects. Voxels outside the image read pixel 0 and are masked.
// DESIGN: the row is 8 lanes of one vector (GCC/Clang vector extensions:
// AVX2 in the AVX2 clone, SSE or NEON pairs elsewhere), and only the 8
// pixel loads are scalar. Written as plain loops over 8 floats, the
// compiler vectorized none of it and made branches of the per-voxel tests
// (in the image, in front of the pixel's surface or behind it: they vary
// along the band and mispredict).
using RowF = float __attribute__((vector_size(4 * kBlockSide)));
using RowI = int32_t __attribute__((vector_size(4 * kBlockSide)));
#define HXMAP_ROW_SELECT(mask, a, b) \
  reinterpret_cast<RowF>(((mask) & reinterpret_cast<RowI>(a)) | (~(mask) & reinterpret_cast<RowI>(b)))

HXMAP_INLINE_IN_CLONES bool lookupRow(const RowLookup& c, const Eigen::Vector3f& p0, float tsdf[kBlockSide],
                                      float w[kBlockSide], const uint8_t* rgb[kBlockSide]) {
  const RowF k = {0, 1, 2, 3, 4, 5, 6, 7};
  const RowF zero = k - k;
  const RowF px = p0.x() + k * c.dx.x(), py = p0.y() + k * c.dx.y(), pz = p0.z() + k * c.dx.z();
  const RowF inv_z = 1.0f / pz;
  const RowF uf = c.fx * px * inv_z + c.cx + 0.5f, vf = c.fy * py * inv_z + c.cy + 0.5f;
  const RowI in = (pz > 0.0f) & (uf >= 0.0f) & (vf >= 0.0f) & (uf < c.Wf) & (vf < c.Hf);
  const RowI u = __builtin_convertvector(HXMAP_ROW_SELECT(in, uf, zero), RowI);
  const RowI v = __builtin_convertvector(HXMAP_ROW_SELECT(in, vf, zero), RowI);
  const RowI index = v * c.width + u;
  RowF depth, conf;
  for (int x = 0; x < kBlockSide; ++x) {
    const PackedDepth::Pixel& p = c.pixels[index[x]];
    depth[x] = p.depth_m;
    conf[x] = p.confidence;
    rgb[x] = p.rgb;
  }
  const RowF sdf = depth - pz;
  const RowI ok = in & (depth > 0.0f) & (sdf >= -c.mu);
  const RowF mu = zero + c.mu;
  const RowF clamped = HXMAP_ROW_SELECT(sdf < mu, sdf, mu);
  const RowF t = HXMAP_ROW_SELECT(ok, clamped, zero), weight = HXMAP_ROW_SELECT(ok, conf, zero);
  std::memcpy(tsdf, &t, sizeof(t));
  std::memcpy(w, &weight, sizeof(weight));
  int32_t any = 0;
  for (int x = 0; x < kBlockSide; ++x) any |= ok[x];
  return any != 0;
}

// fuseGeometry on a row of 8 voxels, as 8 lanes: the row's (sdf, weight)
// pairs split into two vectors and joined again. Returns the blend weight a
// of each voxel.
HXMAP_INLINE_IN_CLONES void fuseGeometryRow(VoxelBlock& blk, int i0, const float* tsdf_in, const float* w_in,
                                            float max_w, float a_out[kBlockSide]) {
  static_assert(sizeof(VoxelGeometry) == 2 * sizeof(float));
  RowF lo, hi, tsdf, w;
  std::memcpy(&lo, &blk.geo[i0], sizeof(lo));
  std::memcpy(&hi, &blk.geo[i0 + kBlockSide / 2], sizeof(hi));
  std::memcpy(&tsdf, tsdf_in, sizeof(tsdf));
  std::memcpy(&w, w_in, sizeof(w));
  const RowF sdf = __builtin_shufflevector(lo, hi, 0, 2, 4, 6, 8, 10, 12, 14);
  const RowF weight = __builtin_shufflevector(lo, hi, 1, 3, 5, 7, 9, 11, 13, 15);
  const RowF new_w = weight + w;
  const RowF zero = w - w, eps = zero + 1e-20f, cap = zero + max_w;
  const RowF a = w / HXMAP_ROW_SELECT(new_w < eps, eps, new_w);  // as std::max(new_w, eps)
  const RowF sdf_out = sdf + a * (tsdf - sdf);
  const RowF w_out = HXMAP_ROW_SELECT(cap < new_w, cap, new_w);  // as std::min(new_w, cap)
  lo = __builtin_shufflevector(sdf_out, w_out, 0, 8, 1, 9, 2, 10, 3, 11);
  hi = __builtin_shufflevector(sdf_out, w_out, 4, 12, 5, 13, 6, 14, 7, 15);
  std::memcpy(static_cast<void*>(&blk.geo[i0]), &lo, sizeof(lo));
  std::memcpy(static_cast<void*>(&blk.geo[i0 + kBlockSide / 2]), &hi, sizeof(hi));
  std::memcpy(a_out, &a, sizeof(a));
}

// fuseAppearance on a row of 8 voxels, as 8 lanes, for the lanes that are
// updated inside the band (w > 0, tsdf < mu); the arithmetic of each lane is
// fuseAppearance's, so the two agree bit for bit (OptimizedKernelAgreesWithReference).
HXMAP_INLINE_IN_CLONES void fuseAppearanceRow(VoxelBlock& blk, int i0, const float* tsdf_in, const float* w_in,
                                              const float* a_in, float mu, const uint8_t* const* rgb) {
  static_assert(sizeof(VoxelStats) == 3 * sizeof(float) && sizeof(VoxelColor) == 4);
  RowF tsdf, w, a;
  std::memcpy(&tsdf, tsdf_in, sizeof(tsdf));
  std::memcpy(&w, w_in, sizeof(w));
  std::memcpy(&a, a_in, sizeof(a));
  const RowF zero = w - w;
  const RowI in_band = (w > zero) & (tsdf < zero + mu);
  // The row's statistics: 24 words (updates, mean, m2) x 8 in three vectors.
  RowF s0, s1, s2;
  std::memcpy(&s0, &blk.stats[i0], sizeof(s0));
  std::memcpy(&s1, reinterpret_cast<const char*>(&blk.stats[i0]) + sizeof(s0), sizeof(s1));
  std::memcpy(&s2, reinterpret_cast<const char*>(&blk.stats[i0]) + 2 * sizeof(s0), sizeof(s2));
  const RowF u01 = __builtin_shufflevector(s0, s1, 0, 3, 6, 9, 12, 15, 0, 0);
  const RowF m01 = __builtin_shufflevector(s0, s1, 1, 4, 7, 10, 13, 0, 0, 0);
  const RowF q01 = __builtin_shufflevector(s0, s1, 2, 5, 8, 11, 14, 0, 0, 0);
  const RowI updates = reinterpret_cast<RowI>(__builtin_shufflevector(u01, s2, 0, 1, 2, 3, 4, 5, 10, 13));
  const RowF mean = __builtin_shufflevector(m01, s2, 0, 1, 2, 3, 4, 8, 11, 14);
  const RowF m2 = __builtin_shufflevector(q01, s2, 0, 1, 2, 3, 4, 9, 12, 15);
  if (rgb) {
    RowI pix, col;
    for (int x = 0; x < kBlockSide; ++x) {
      uint32_t p;
      std::memcpy(&p, rgb[x], sizeof(p));
      pix[x] = static_cast<int32_t>(p);
    }
    std::memcpy(&col, &blk.color[i0], sizeof(col));
    // The first in-band observation sets the color (fuseAppearance).
    const RowF ac = HXMAP_ROW_SELECT(updates == 0, zero + 1.0f, a);
    RowI out = col & static_cast<int32_t>(0xFF000000u);  // the flags stay
    for (int ch = 0; ch < 3; ++ch) {
      const RowF k = __builtin_convertvector((col >> (8 * ch)) & 0xFF, RowF);
      const RowF o = __builtin_convertvector((pix >> (8 * ch)) & 0xFF, RowF);
      const RowI v = __builtin_convertvector(k + ac * (o - k) + 0.5f, RowI) & 0xFF;
      out |= v << (8 * ch);
    }
    col = (in_band & out) | (~in_band & col);
    std::memcpy(static_cast<void*>(&blk.color[i0]), &col, sizeof(col));
  }
  const RowI n = updates + 1;
  const RowF delta = tsdf - mean;
  const RowF mean_out = mean + delta / __builtin_convertvector(n, RowF);
  const RowF m2_out = m2 + delta * (tsdf - mean_out);
  const RowI nu = (in_band & n) | (~in_band & updates);
  const RowF nm = HXMAP_ROW_SELECT(in_band, mean_out, mean), nq = HXMAP_ROW_SELECT(in_band, m2_out, m2);
  const RowF nuf = reinterpret_cast<RowF>(nu);
  const RowF o01 = __builtin_shufflevector(nuf, nm, 0, 8, 0, 1, 9, 0, 2, 10);
  s0 = __builtin_shufflevector(o01, nq, 0, 1, 8, 3, 4, 9, 6, 7);
  const RowF o12 = __builtin_shufflevector(nuf, nm, 0, 3, 11, 0, 4, 12, 0, 5);
  s1 = __builtin_shufflevector(o12, nq, 10, 1, 2, 11, 4, 5, 12, 7);
  const RowF o23 = __builtin_shufflevector(nuf, nm, 13, 0, 6, 14, 0, 7, 15, 0);
  s2 = __builtin_shufflevector(o23, nq, 0, 13, 2, 3, 14, 5, 6, 15);
  std::memcpy(static_cast<void*>(&blk.stats[i0]), &s0, sizeof(s0));
  std::memcpy(reinterpret_cast<char*>(&blk.stats[i0]) + sizeof(s0), &s1, sizeof(s1));
  std::memcpy(reinterpret_cast<char*>(&blk.stats[i0]) + 2 * sizeof(s0), &s2, sizeof(s2));
}
#undef HXMAP_ROW_SELECT

// A voxel refinement saw through (kVoxelSeenThrough) takes no observation
// that puts it more than a voxel behind a surface; one that puts it within
// a voxel of a surface clears the flag (something is there now).
// DESIGN: fusion's projective distances fill up to mu behind whatever a
// view sees, so behind a thin part (a rod) every frontal view adds the
// negative shadow that refinement, from the views that saw through it,
// cleared: on the quality room, 74-79 of a rod's shadow voxels written
// outside the surface by one job were inside again ten keyframes later.
// Only blocks with a flagged voxel pay for the check (the flags sit with
// the colors, away from the geometry the row loop reads).
HXMAP_INLINE_IN_CLONES void maskSeenThrough(float voxel, VoxelBlock& block, int i0, const float* tsdf, float* w,
                                            int n = kBlockSide) {
  for (int x = 0; x < n; ++x) {
    uint8_t& flags = block.color[i0 + x].flags;
    if (!(flags & kVoxelSeenThrough) || w[x] <= 0.0f) continue;
    if (tsdf[x] < -voxel) {
      w[x] = 0.0f;
    } else if (tsdf[x] <= voxel) {
      flags &= static_cast<uint8_t>(~kVoxelSeenThrough);
    }
  }
}

// Every row of 8 voxels of a block whose first voxel center is origin_cam
// (camera frame) that the observation updates: body(first voxel index,
// tsdf, w, rgb) as lookupRow fills them (w masked by maskSeenThrough where
// the block has flagged voxels).
template <typename Body>
HXMAP_INLINE_IN_CLONES void forEachUpdatedRow(const RowLookup& c, VoxelBlock& block, const Eigen::Vector3f& origin_cam,
                                              const Body& body) {
  const bool flagged = block.seen_through > 0;
  for (int z = 0; z < kBlockSide; ++z) {
    for (int y = 0; y < kBlockSide; ++y) {
      const Eigen::Vector3f p0 = origin_cam + c.dz * static_cast<float>(z) + c.dy * static_cast<float>(y);
      float tsdf[kBlockSide], w[kBlockSide];
      const uint8_t* rgb[kBlockSide];
      if (!lookupRow(c, p0, tsdf, w, rgb)) continue;
      const int i0 = VoxelBlock::index(0, y, z);
      if (flagged) maskSeenThrough(c.voxel, block, i0, tsdf, w);
      body(i0, tsdf, w, rgb);
    }
  }
}

// Fuses the observation into one block; returns the voxels updated.
// Geometry for the whole row (vectorizable), then color and statistics for
// the voxels inside the band.
HXMAP_SIMD_CLONES size_t fuseBlock(const RowLookup& c, VoxelBlock& block, const Eigen::Vector3f& origin_cam,
                                   float max_w, bool has_rgb) {
  size_t updates = 0;
  forEachUpdatedRow(c, block, origin_cam,
                    [&](int i0, const float* tsdf, const float* w, const uint8_t* const* rgb)
                        HXMAP_LAMBDA_INLINE_IN_CLONES {
                          float a[kBlockSide];
                          fuseGeometryRow(block, i0, tsdf, w, max_w, a);
                          for (int x = 0; x < kBlockSide; ++x) updates += w[x] > 0.0f;
                          fuseAppearanceRow(block, i0, tsdf, w, a, c.mu, has_rgb ? rgb : nullptr);
                        });
  return updates;
}

// The inverse of fuseBlock for an observation fused earlier.
size_t removeFromBlock(const RowLookup& c, VoxelBlock& block, const Eigen::Vector3f& origin_cam, bool has_rgb) {
  size_t updates = 0;
  forEachUpdatedRow(c, block, origin_cam, [&](int i0, const float* tsdf, const float* w, const uint8_t* const* rgb) {
    for (int x = 0; x < kBlockSide; ++x) {
      if (w[x] <= 0.0f) continue;
      ++updates;
      removeObservation(block, i0 + x, tsdf[x], w[x], c.mu, has_rgb ? rgb[x] : nullptr);
    }
  });
  return updates;
}

template <bool kRemove>
IntegrationStats fuseObservation(TsdfMap& map, const DepthObservation& obs, const ParallelFor& parallel) {
  IntegrationStats stats;
  const PackedDepth img = packObservation(map, obs);
  const std::vector<int32_t> blocks = allocateBand(map, img, obs.T_world_cam, &stats.blocks_allocated);
  stats.blocks_in_band = blocks.size();
  const Eigen::Isometry3f T_cam_world = obs.T_world_cam.inverse();
  const Eigen::Matrix3f R = T_cam_world.linear();
  const float vs = map.voxelSize(), mu = map.truncation();
  const float max_w = static_cast<float>(map.params().max_weight);
  const bool has_rgb = !obs.rgb.empty();
  const RowLookup c{R.col(0) * vs,
                    R.col(1) * vs,
                    R.col(2) * vs,
                    img.fx,
                    img.fy,
                    img.cx,
                    img.cy,
                    static_cast<float>(img.width),
                    static_cast<float>(img.height),
                    mu,
                    vs,
                    img.data(),
                    img.width};
  map.prepareWrites(blocks);  // copies made here, not by the threads below
  std::atomic<size_t> updated{0};
  parallel(blocks.size(), [&](size_t begin, size_t end) {
    size_t local_updates = 0;
    for (size_t bi = begin; bi < end; ++bi) {
      const int32_t b = blocks[bi];
      VoxelBlock& block = map.block(b);
      const Eigen::Vector3f origin_world =
          (map.key(b) * kBlockSide).cast<float>() * vs + Eigen::Vector3f::Constant(0.5f * vs);
      const Eigen::Vector3f origin_cam = T_cam_world * origin_world;
      local_updates +=
          kRemove ? removeFromBlock(c, block, origin_cam, has_rgb) : fuseBlock(c, block, origin_cam, max_w, has_rgb);
    }
    updated += local_updates;
  });
  stats.voxels_updated = updated;
  map.markChanged(blocks);
  return stats;
}

}  // namespace

IntegrationStats integrate(TsdfMap& map, const DepthObservation& obs, const ParallelFor& parallel) {
  return fuseObservation<false>(map, obs, parallel);
}

IntegrationStats deintegrate(TsdfMap& map, const DepthObservation& obs, const ParallelFor& parallel) {
  return fuseObservation<true>(map, obs, parallel);
}

IntegrationStats integrateReference(TsdfMap& map, const DepthObservation& obs) {
  IntegrationStats stats;
  const std::vector<int32_t> blocks = allocateBand(map, obs, &stats.blocks_allocated);
  stats.blocks_in_band = blocks.size();
  const Eigen::Isometry3d T_cam_world = obs.T_world_cam.cast<double>().inverse();
  const double mu = map.params().truncation_m;
  // Reads every 2^level-th pixel like the optimized kernel: the nearest such pixel.
  const double step = static_cast<double>(1 << integrationLevel(map, obs.camera));
  for (const int32_t b : blocks) {
    for (int i = 0; i < kBlockVoxels; ++i) {
      const int x = i % kBlockSide, y = (i / kBlockSide) % kBlockSide, z = i / (kBlockSide * kBlockSide);
      const Eigen::Vector3i global = map.key(b) * kBlockSide + Eigen::Vector3i(x, y, z);
      const Eigen::Vector3d p = T_cam_world * map.voxelCenter(global).cast<double>();
      if (p.z() <= 0) continue;
      const double u = obs.camera.fx * p.x() / p.z() + obs.camera.cx;
      const double v = obs.camera.fy * p.y() / p.z() + obs.camera.cy;
      const int ui = static_cast<int>(std::lround(u / step) * step),
                vi = static_cast<int>(std::lround(v / step) * step);
      if (ui < 0 || vi < 0 || ui >= obs.depth_m.cols || vi >= obs.depth_m.rows) continue;
      const double d = obs.depth_m.at<float>(vi, ui);
      if (!(d > 0) || d > map.params().max_integration_depth_m) continue;
      const double sdf = d - p.z();
      if (sdf < -mu) continue;
      const int cs = confidenceShift(obs);
      const double c = obs.confidence.empty() ? 1.0 : obs.confidence.at<float>(vi >> cs, ui >> cs);
      if (c < map.params().min_confidence || c <= 0) continue;
      const uint8_t* rgb = obs.rgb.empty() ? nullptr : obs.rgb.ptr<uint8_t>(vi) + 3 * ui;
      const float tsdf = static_cast<float>(std::min(sdf, mu));
      VoxelBlock& blk = map.block(b);
      float w = static_cast<float>(c);
      if (blk.seen_through) {
        maskSeenThrough(map.voxelSize(), blk, i, &tsdf, &w, 1);
        if (!(w > 0.0f)) continue;
      }
      const float a = fuseGeometry(blk, i, tsdf, w, static_cast<float>(map.params().max_weight));
      if (tsdf < static_cast<float>(mu)) fuseAppearance(blk, i, tsdf, a, rgb);
      ++stats.voxels_updated;
    }
  }
  map.markChanged(blocks);
  return stats;
}

}  // namespace hxmap::alg
