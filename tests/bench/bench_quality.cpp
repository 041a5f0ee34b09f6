// Quality-guided selection benchmark (paper 3.2).
//
// 1. Validation on the synthetic quality room, whose bad regions are known
//    by construction (thin rods, a board's occlusion edges, a wall patch
//    with 8x depth noise, a shelf top seen only at a grazing angle, next to
//    clean walls): the frontend maps the "inspect" sequence with default
//    parameters, then the blocks chosen for refinement are compared with the
//    known-bad blocks: a voxel center within 1.5 voxels of such a region, or
//    a block where the TSDF map is measurably wrong against the exact
//    ground-truth mesh (less than 80 % of the observed true surface in the
//    block, or of the map's own surface there, within 1 cm of the other).
//    The rest are clean. Prints precision (share of the chosen volume
//    inside known-bad regions) and recall (share of the known-bad blocks
//    chosen) at the configured budget and at larger ones, and each
//    indicator's mean per region kind. A second figure per budget also
//    counts as bad the surfaces the trajectory observes poorly (fewer than 3
//    views at an incidence below 75 degrees, from ground truth) where the
//    map came out right anyway: what CGN is meant to find, but not a place
//    where the map needs refinement.
// 2. Cost: scoring + ROI extraction per keyframe on the shared TUM slice at
//    640x480, one core, every frame made a keyframe; median in ms.
//
//   bench_quality [quality_sequence_dir|-] [tum_dir] [inspect|sweep]
// Without a sequence folder (or with "-") the quality room is rendered in
// memory (about 20 s on one core) along the given trajectory: "inspect"
// (default) or "sweep", a second path past the same wall to check that
// what was tuned on one holds on the other. HXMAP_BENCH_PRIORITY_RULE=sum
// scores with the method's weighted sum instead of the default maximum.
// Prints numbers; asserts nothing.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/mesh_metrics.hpp"
#include "hxmap/eval/triangle_bvh.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "quality_room_sequence.hpp"

using namespace hxmap;

namespace {
double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}
uint64_t pack(const alg::BlockKey& k) { return alg::packBlockKey(k); }

// Kind of known-bad region a block touches: -1 none, else the primitive index.
int badKind(const drv::SyntheticScene& scene, const alg::BlockKey& key, float voxel_m) {
  float best = 1e9f;
  int kind = -1;
  for (int i = 0; i < alg::kBlockVoxels; ++i) {
    const Eigen::Vector3i g = key * alg::kBlockSide + Eigen::Vector3i(i % 8, (i / 8) % 8, i / 64);
    const Eigen::Vector3f c = (g.cast<float>() + Eigen::Vector3f::Constant(0.5f)) * voxel_m;
    int k = -1;
    const float d = scene.badDistance(c, &k);
    if (d < best) {
      best = d;
      kind = k;
    }
  }
  return best <= 1.5f * voxel_m ? kind : -1;
}
// Blocks the trajectory observes well, from ground truth: views (every 6th
// frame, about the keyframe rate) in which at least 4 rays of a 160x120 grid
// meet the block's surface at an incidence below 75 degrees within 4 m.
// `seen` gets the blocks whose surface any of those rays meets at all.
std::unordered_set<uint64_t> wellObserved(const drv::SyntheticScene& scene, const alg::PinholeCamera& cam,
                                          const Trajectory& gt, float block_m, float voxel_m, int min_views,
                                          std::unordered_set<uint64_t>& seen) {
  std::unordered_map<uint64_t, int> views;
  for (size_t f = 0; f < gt.size(); f += 6) {
    const Eigen::Isometry3f T_world_cam = gt[f].T_world_cam.cast<float>();
    std::unordered_map<uint64_t, int> hits;
    for (int v = 2; v < cam.height; v += 4) {
      for (int u = 2; u < cam.width; u += 4) {
        const Eigen::Vector3f ray = cam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
        const Eigen::Vector3f dir = (T_world_cam.linear() * ray).normalized();
        float t = 0;
        Eigen::Vector3f n;
        int k = -1;
        if (!scene.raycast(T_world_cam.translation(), dir, t, n, k)) continue;
        // The surface point counts for the blocks within half a voxel of it
        // along its normal: a surface on a block's face (the floor at z = 0)
        // belongs to the blocks on both sides, as the map's zero crossing
        // between their voxels does.
        const Eigen::Vector3f p = T_world_cam.translation() + t * dir;
        const bool good = t / ray.norm() <= 4.0f && std::abs(n.dot(dir)) >= 0.26f;
        uint64_t last = 0;
        for (const float side : {-0.5f, 0.5f}) {
          const Eigen::Vector3f q = (p + side * voxel_m * n) / block_m;
          const uint64_t key =
              pack(alg::BlockKey(alg::floorToInt(q.x()), alg::floorToInt(q.y()), alg::floorToInt(q.z())));
          if (side > 0 && key == last) break;
          last = key;
          seen.insert(key);
          if (good) ++hits[key];
        }
      }
    }
    for (const auto& [key, n] : hits) views[key] += n >= 4;
  }
  std::unordered_set<uint64_t> out;
  for (const auto& [key, n] : views) {
    if (n >= min_views) out.insert(key);
  }
  return out;
}

// Blocks where the TSDF map is measurably wrong: of the ground-truth
// surface in the block that the trajectory observes, or of the map's own
// surface in the block, less than `min_share` lies within 1 cm of the other
// (each counted where it has at least `min_samples` samples).
std::unordered_set<uint64_t> measuredBad(const alg::TriangleMesh& recon, const alg::TriangleMesh& gt_mesh,
                                         const alg::PinholeCamera& cam, const Trajectory& gt, float block_m,
                                         double min_share, int min_samples) {
  struct Count {
    int n = 0, ok = 0;
  };
  std::unordered_map<uint64_t, Count> gt_count, rc_count;
  auto keyOf = [&](const Eigen::Vector3f& p) {
    const Eigen::Vector3f q = p / block_m;
    return pack(alg::BlockKey(alg::floorToInt(q.x()), alg::floorToInt(q.y()), alg::floorToInt(q.z())));
  };
  const alg::TriangleBvh rc_bvh(recon), gt_bvh(gt_mesh);
  {
    const auto pts = alg::sampleSurface(gt_mesh, 400000, 3);
    Trajectory views;
    for (size_t f = 0; f < gt.size(); f += 6) views.push_back(gt[f]);
    const std::vector<bool> vis = alg::visibleFromAny(pts, gt_mesh, cam, views, 4.0);
    for (size_t i = 0; i < pts.size(); ++i) {
      if (!vis[i]) continue;
      Count& c = gt_count[keyOf(pts[i])];
      ++c.n;
      c.ok += rc_bvh.distance(pts[i], 0.02f) <= 0.01f;
    }
  }
  for (const auto& p : alg::sampleSurface(recon, 400000, 4)) {
    Count& c = rc_count[keyOf(p)];
    ++c.n;
    c.ok += gt_bvh.distance(p, 0.02f) <= 0.01f;
  }
  std::unordered_set<uint64_t> out;
  for (const auto* counts : {&gt_count, &rc_count}) {
    for (const auto& [key, c] : *counts) {
      if (c.n < min_samples) continue;
      if (c.ok < min_share * c.n) out.insert(key);
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const drv::SyntheticScene scene = test::benchQualityRoom();
  test::BenchSequence seq;
  const std::string trajectory = argc > 3 ? argv[3] : "inspect";
  if (!test::loadOrRenderQualityRoom(argc > 1 ? argv[1] : "", seq, trajectory)) return 2;
  const std::vector<RgbdFrame>& frames = seq.frames;
  const Trajectory& gt = seq.ground_truth;
  const alg::PinholeCamera& cam = seq.camera;

  rt::FrontendParams params;
  params.relocalization.enabled = false;  // the keyframe stage times scoring alone
  if (const char* v = std::getenv("HXMAP_BENCH_VOXELS")) {  // one voxel size, truncation 4 voxels
    params.tsdf.voxel_size_m = static_cast<float>(std::atof(v));
    params.tsdf.truncation_m = 4 * params.tsdf.voxel_size_m;
  }
  if (const char* v = std::getenv("HXMAP_BENCH_PRIORITY_RULE")) params.quality.priority_rule = v;  // max or sum
  rt::Frontend fe(cam, params);
  if (!gt.empty()) fe.setInitialPose(gt.front().T_world_cam);
  std::vector<double> quality_ms;
  for (const auto& f : frames) {
    const auto r = fe.process(f);
    if (r.keyframe) quality_ms.push_back(r.stage_ms[rt::kKeyframe]);
  }
  const float vs = fe.map().voxelSize();
  std::unordered_set<uint64_t> chosen;
  for (const auto& roi : fe.rois()) {
    for (const auto& k : roi.blocks) chosen.insert(pack(k));
  }
  // Region kinds: primitive index -> name.
  std::map<int, std::string> names{{-1, "clean"}, {-2, "map error"}, {-3, "under-observed"}};
  for (int k = 0; k < static_cast<int>(scene.primitives().size()); ++k) {
    const auto& p = scene.primitives()[k];
    if (p.bad == drv::Primitive::Bad::kNo) continue;
    names[k] = test::badRegionName(p);
  }
  struct Tally {
    size_t blocks = 0, chosen = 0;
    std::array<double, alg::kIndicatorCount + 1> sum{};
  };
  std::unordered_set<uint64_t> seen;
  const auto well = wellObserved(scene, cam, gt, fe.map().blockSize(), vs, 3, seen);
  const auto map_bad =
      measuredBad(alg::extractMesh(fe.map(), alg::MeshParams{}), scene.mesh(), cam, gt, fe.map().blockSize(), 0.8, 20);
  // -1 clean, -2 map error, -3 under-observed (map right), else the primitive.
  auto regionKind = [&](const alg::BlockKey& key) {
    const int k = badKind(scene, key, vs);
    if (k >= 0) return k;
    if (map_bad.count(pack(key))) return -2;
    return well.count(pack(key)) || !seen.count(pack(key)) ? -1 : -3;
  };
  auto isBad = [](int kind) { return kind >= 0 || kind == -2; };
  std::map<std::string, Tally> by_kind;
  size_t bad = 0, bad_chosen = 0;
  // HXMAP_BENCH_CSV=path: every block's raw and normalized indicators with its region kind.
  FILE* csv = std::getenv("HXMAP_BENCH_CSV") ? std::fopen(std::getenv("HXMAP_BENCH_CSV"), "w") : nullptr;
  if (csv) std::fprintf(csv, "bx,by,bz,kind,cgn,uf,obg,rm,cgn_n,uf_n,obg_n,rm_n,priority,chosen\n");
  for (const auto& s : fe.blockScores()) {
    const int kind = regionKind(s.key);
    const bool is_chosen = chosen.count(pack(s.key)) > 0;
    if (csv) {
      std::fprintf(csv, "%d,%d,%d,%s,%.5f,%.5f,%.5f,%.5f,%.4f,%.4f,%.4f,%.4f,%.4f,%d\n", s.key.x(), s.key.y(),
                   s.key.z(), names[kind].c_str(), s.raw[0], s.raw[1], s.raw[2], s.raw[3], s.normalized[0],
                   s.normalized[1], s.normalized[2], s.normalized[3], s.priority, is_chosen ? 1 : 0);
    }
    Tally& t = by_kind[names[kind]];
    ++t.blocks;
    t.chosen += is_chosen;
    for (int i = 0; i < alg::kIndicatorCount; ++i) t.sum[i] += s.normalized[i];
    t.sum[alg::kIndicatorCount] += s.priority;
    if (isBad(kind)) {
      ++bad;
      bad_chosen += is_chosen;
    }
  }
  if (csv) std::fclose(csv);
  std::printf(
      "quality room: %zu frames, %zu keyframes, %zu blocks scored, %zu known-bad, %zu chosen in %zu ROIs "
      "(top_fraction %.2f, max_blocks %d)\n",
      frames.size(), fe.keyframes(), fe.blockScores().size(), bad, chosen.size(), fe.rois().size(),
      params.quality.top_fraction, params.quality.max_blocks);
  std::printf("  precision %.1f%% (chosen volume inside known-bad regions; target >= 80%%)\n",
              chosen.empty() ? 0.0 : 100.0 * static_cast<double>(bad_chosen) / static_cast<double>(chosen.size()));
  std::printf("  recall    %.1f%% (known-bad blocks chosen; target >= 70%%)\n",
              bad ? 100.0 * static_cast<double>(bad_chosen) / static_cast<double>(bad) : 0.0);
  std::printf("  mean normalized indicator per region kind:\n  %-14s %6s %6s %6s %6s %6s %6s %7s\n", "kind", "blocks",
              "CGN", "UF", "OBG", "RM", "S", "chosen");
  for (const auto& [name, t] : by_kind) {
    const double n = static_cast<double>(std::max<size_t>(1, t.blocks));
    std::printf("  %-14s %6zu %6.2f %6.2f %6.2f %6.2f %6.2f %6.0f%%\n", name.c_str(), t.blocks, t.sum[0] / n,
                t.sum[1] / n, t.sum[2] / n, t.sum[3] / n, t.sum[4] / n, 100.0 * static_cast<double>(t.chosen) / n);
  }
  {
    // Precision and recall of the top blocks by S at other budgets; the
    // second pair also counts the under-observed surfaces as bad.
    const auto& scores = fe.blockScores();
    size_t bad_or_under = 0;
    for (const auto& sc : scores) bad_or_under += regionKind(sc.key) != -1;
    for (double budget : {0.1, 0.15, 0.18, 0.2, 0.25, 0.3}) {
      const size_t k = static_cast<size_t>(std::ceil(budget * static_cast<double>(scores.size())));
      size_t hit = 0, hit_or_under = 0;
      for (size_t i = 0; i < k && i < scores.size(); ++i) {
        const int kind = regionKind(scores[i].key);
        hit += isBad(kind);
        hit_or_under += kind != -1;
      }
      auto pct = [](size_t a, size_t b) { return b ? 100.0 * static_cast<double>(a) / static_cast<double>(b) : 0.0; };
      std::printf(
          "  budget %.0f%% of scored blocks: precision %.1f%% recall %.1f%%  (under-observed counted bad: %.1f%% "
          "%.1f%%)\n",
          100 * budget, pct(hit, k), pct(hit, bad), pct(hit_or_under, k), pct(hit_or_under, bad_or_under));
    }
  }
  std::printf("  quality stage per keyframe on this run: median %.2f ms\n", median(quality_ms));

  // Cost on the TUM slice, one core, every frame a keyframe.
  const std::string tum =
      argc > 2 ? argv[2] : std::string(HXMAP_SHARED_DATA) + "/tum/rgbd_dataset_freiburg1_xyz_first40";
  auto ds = drv::Dataset::open(tum);
  if (!ds) {
    std::fprintf(stderr, "%s\n", ds.message().c_str());
    return 2;
  }
  rt::FrontendParams every;
  every.tracking.keyframe_translation_m = 0;
  every.tracking.keyframe_interval_s = 0;
  every.refine.enabled = false;          // scoring alone (making refinement jobs is timed in the same stage)
  every.relocalization.enabled = false;  // and so are the keyframe database's features
  std::vector<double> tum_ms;
  for (int rep = 0; rep < 3; ++rep) {
    rt::Frontend tfe((*ds)->camera(), every);
    for (size_t i = 0; i < (*ds)->size(); ++i) {
      auto f = (*ds)->load(i);
      if (!f) continue;
      const auto r = tfe.process(*f);
      if (r.keyframe && i > 0) tum_ms.push_back(r.stage_ms[rt::kKeyframe]);
    }
  }
  std::printf(
      "TUM slice %dx%d, one core: scoring + ROI extraction per keyframe median %.2f ms (target <= 3), "
      "%zu keyframes\n",
      (*ds)->camera().width, (*ds)->camera().height, median(tum_ms), tum_ms.size());
  return 0;
}
