// Implicit local refinement benchmark (paper 3.3).
//
// 1. Synthetic quality room (thin rods, a board's sharp edges, a noisy wall
//    patch, a shelf seen at a grazing angle; exact ground-truth mesh): at
//    full size with 2 cm and 1 cm voxels, and at half size with 1 cm voxels
//    (its rods and edges are then as thin against the voxels as at full
//    size with 2 cm). The same frames mapped twice in this process,
//    TSDF only and hybrid (each keyframe's ROI jobs run to their end and
//    are written back before the next frame, as `hxmap run` does; the
//    hybrid mesh is the map's own after the write-backs, the one `hxmap
//    run` writes by default; "+detail" adds the refined regions' detail
//    layer, made here with refine.detail_min_share 0.5 unless a
//    configuration file is given). Mesh
//    precision / recall / F1 at 1 cm over the whole scene and inside the
//    refined ROIs: precision from the reconstruction's samples inside the
//    ROI boxes against the whole ground truth, recall from the observed
//    ground truth's samples inside the boxes against the whole
//    reconstruction (no border effects from cropping). Observed: in view
//    of a frame, not occluded, and not only at the grazing angles the
//    synthetic sensor returns no depth for.
// 2. Depth L1 of the map's renderings against the keyframes' input depth,
//    inside each job's ROI, just before and just after its write-back, on
//    the quality room and on the shared Replica slice: over the pixels the
//    map renders both times, and apart, the pixels the write-back made
//    render (completion of surfaces fusion never observed).
// 3. Time per ROI job and per iteration, memory per ROI.
//
//   bench_refine [quality_sequence_dir|-] [replica_dir|-] [config.yaml]
// The configuration applies, except voxel size and truncation (4 voxels).
// A quality-room folder (`hxmap synth --scene quality --trajectory inspect
// --frames 240 [--scale 0.5]`) holds one scale: give it in
// HXMAP_BENCH_SCALE (default 1). HXMAP_BENCH_SCALE and HXMAP_BENCH_VOXELS
// (e.g. "0.01") each limit the cases to that scale or voxel size. Per kind of region, the
// precision and recall inside the ROIs show where the F1 change comes
// from. Prints numbers; asserts nothing.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "commands.hpp"
#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/mesh_metrics.hpp"
#include "hxmap/eval/triangle_bvh.hpp"
#include "hxmap/frontend/frontend.hpp"
#include "hxmap/tsdf/mesh_extract.hpp"
#include "hxmap/tsdf/raycast.hpp"
#include "quality_room_sequence.hpp"

using namespace hxmap;

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

alg::TriangleMesh crop(const alg::TriangleMesh& m, const std::vector<Eigen::AlignedBox3f>& boxes) {
  alg::TriangleMesh out;
  out.vertices = m.vertices;
  for (const auto& t : m.triangles) {
    const Eigen::Vector3f c = (m.vertices[t[0]] + m.vertices[t[1]] + m.vertices[t[2]]) / 3.0f;
    for (const auto& b : boxes) {
      if (b.contains(c)) {
        out.triangles.push_back(t);
        break;
      }
    }
  }
  return out;
}

struct Scores {
  double precision = 0, recall = 0, f1 = 0;
};
// Samples of the ground truth inside the boxes that the sensor observed
// (occlusion by the whole scene, not only by what lies in the boxes).
std::vector<Eigen::Vector3f> observedInside(const alg::TriangleMesh& gt, const std::vector<Eigen::AlignedBox3f>& boxes,
                                            const alg::ObservedBy& observed, int samples, uint64_t seed) {
  const alg::TriangleMesh gc = crop(gt, boxes);
  if (gc.empty()) return {};
  std::vector<Eigen::Vector3f> normals;
  const auto all = alg::sampleSurface(gc, samples, seed, &normals);
  return alg::keepObserved(all, normals, gt, observed);
}

Scores insideBoxes(const alg::TriangleMesh& recon, const alg::TriangleMesh& gt,
                   const std::vector<Eigen::AlignedBox3f>& boxes, const alg::ObservedBy& observed,
                   const alg::MeshMetricsParams& mp) {
  Scores s;
  const alg::TriangleMesh rc = crop(recon, boxes);
  if (!rc.empty()) s.precision = alg::computeMeshMetrics(rc, gt, mp).point_to_surface.precision_fine;
  const auto pts = observedInside(gt, boxes, observed, mp.samples, mp.seed + 1);
  if (!pts.empty() && !recon.empty()) {
    const alg::TriangleBvh rec_bvh(recon);
    size_t within = 0;
    for (const auto& p : pts) within += rec_bvh.distance(p, 0.02f) <= mp.threshold_fine_m;
    s.recall = static_cast<double>(within) / static_cast<double>(pts.size());
  }
  s.f1 = s.precision + s.recall > 0 ? 2 * s.precision * s.recall / (s.precision + s.recall) : 0;
  return s;
}

// The kind of region a point lies in: the nearest known-bad primitive
// within 3 voxels, else clean.
std::string regionKind(const drv::SyntheticScene& scene, const Eigen::Vector3f& p, float voxel) {
  int k = -1;
  const float d_bad = scene.badDistance(p, &k);
  if (!(d_bad < 3 * voxel && k >= 0)) return "clean";
  return test::badRegionName(scene.primitives()[static_cast<size_t>(k)]);
}

// Per kind of region, the share of `pts` within 1 cm of `to`, the kind's
// share of the samples and the mean distance: where refinement helps and
// where it hurts.
void withinByKind(const char* label, const std::vector<Eigen::Vector3f>& pts, const alg::TriangleBvh& to,
                  const drv::SyntheticScene& scene, float voxel) {
  std::map<std::string, std::array<double, 3>> by;  // samples, within 1 cm, sum of distances
  for (const auto& p : pts) {
    const float d = to.distance(p, 0.05f);
    auto& a = by[regionKind(scene, p, voxel)];
    a[0] += 1;
    a[1] += d <= 0.01f;
    a[2] += std::min(d, 0.05f);
  }
  std::printf("    %-7s", label);
  for (const auto& [kind, a] : by) {
    std::printf("  %s: %.0f%% of %.0f%% (mean %.1f mm)", kind.c_str(), 100 * a[1] / a[0], 100 * a[0] / pts.size(),
                1000 * a[2] / a[0]);
  }
  std::printf("\n");
}

// Precision: the reconstruction's samples inside the boxes against the
// ground truth.
void precisionByKind(const char* label, const alg::TriangleMesh& recon, const alg::TriangleBvh& gt,
                     const drv::SyntheticScene& scene, const std::vector<Eigen::AlignedBox3f>& boxes, float voxel) {
  const alg::TriangleMesh rc = crop(recon, boxes);
  if (rc.empty()) return;
  withinByKind(label, alg::sampleSurface(rc, 100000, 7), gt, scene, voxel);
}

// Recall: the observed ground truth's samples inside the boxes against the
// reconstruction.
void recallByKind(const char* label, const alg::TriangleMesh& recon, const alg::TriangleMesh& gt,
                  const alg::ObservedBy& observed, const drv::SyntheticScene& scene,
                  const std::vector<Eigen::AlignedBox3f>& boxes, float voxel) {
  if (recon.empty()) return;
  const auto pts = observedInside(gt, boxes, observed, 100000, 11);
  if (pts.empty()) return;
  withinByKind(label, pts, alg::TriangleBvh(recon), scene, voxel);
}

// |rendered - input| depth over the keyframes' pixels whose input surface
// lies in the job's box (NaN where the map renders no surface), in a fixed
// pixel order so that a job's before and after line up.
std::vector<float> roiDepthErrors(const alg::TsdfMap& map, const rt::RefineJob& job) {
  std::vector<float> out;
  for (const auto& kf : job.keyframes) {
    const alg::ModelView mv = alg::raycast(map, kf.camera, kf.T_world_cam, alg::RaycastParams{});
    for (int v = 0; v < kf.depth.rows; ++v) {
      for (int u = 0; u < kf.depth.cols; ++u) {
        const float z = kf.depth.at<float>(v, u);
        if (!(z > 0)) continue;
        const Eigen::Vector3f p =
            kf.T_world_cam * kf.camera.backproject(static_cast<float>(u), static_cast<float>(v), z);
        if (!job.roi.box_world.contains(p)) continue;
        const float zr = mv.depth.at<float>(v, u);
        out.push_back(zr > 0 ? std::abs(zr - z) : std::numeric_limits<float>::quiet_NaN());
      }
    }
  }
  return out;
}

// Before vs after over the pixels rendered both times, and the pixels a
// write-back made render (completion) or stop rendering.
struct DepthL1 {
  std::vector<double> before_m, after_m, filled_m;
  size_t pixels = 0, missing_before = 0, missing_after = 0;
  void add(const std::vector<float>& b, const std::vector<float>& a) {
    for (size_t i = 0; i < b.size() && i < a.size(); ++i) {
      ++pixels;
      const bool hb = std::isfinite(b[i]), ha = std::isfinite(a[i]);
      missing_before += !hb;
      missing_after += !ha;
      if (hb && ha) {
        before_m.push_back(b[i]);
        after_m.push_back(a[i]);
      } else if (ha) {
        filled_m.push_back(a[i]);
      }
    }
  }
};

// A job's CPU time per phase (this thread's CPU clock, so load elsewhere on
// the machine does not count).
struct PhaseClock final : alg::RefineProbe {
  std::array<double, alg::kRefinePhases> ms{};
  alg::RefinePhase current = alg::RefinePhase::kOutside;
  double since = now();
  static double now() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
  }
  void enter(alg::RefinePhase phase) override {
    const double t = now();
    ms[static_cast<size_t>(current)] += t - since;
    current = phase, since = t;
  }
  double inside() const {
    double sum = 0;
    for (size_t i = 1; i < ms.size(); ++i) sum += ms[i];
    return sum;
  }
};

struct HybridRun {
  alg::TriangleMesh tsdf_mesh, hybrid_mesh, detail_mesh;
  size_t details = 0;
  std::vector<Eigen::AlignedBox3f> boxes;
  std::vector<double> job_ms, iteration_ms, setup_ms, memory_mb, iterations, rays, free_rays, job_cpu_ms;
  std::array<double, alg::kRefinePhases> phase_ms{};  ///< all jobs
  double all_iterations = 0;
  DepthL1 depth;
  size_t jobs = 0, converged = 0, out_of_time = 0;
  double tsdf_s = 0, hybrid_s = 0;
  Trajectory poses;
};

HybridRun mapTwice(const std::vector<RgbdFrame>& frames, const alg::PinholeCamera& cam, const Trajectory& gt,
                   rt::FrontendParams params) {
  HybridRun out;
  using Clock = std::chrono::steady_clock;
  alg::MeshParams mp;
  {
    rt::FrontendParams p = params;
    p.refine.enabled = false;
    rt::Frontend fe(cam, p);
    if (!gt.empty()) fe.setInitialPose(gt.front().T_world_cam);
    const auto t0 = Clock::now();
    for (const auto& f : frames) fe.process(f);
    out.tsdf_s = std::chrono::duration<double>(Clock::now() - t0).count();
    out.tsdf_mesh = alg::extractMesh(fe.map(), mp);
  }
  rt::Frontend fe(cam, params);
  if (!gt.empty()) fe.setInitialPose(gt.front().T_world_cam);
  const auto t0 = Clock::now();
  size_t done = 0;
  for (const auto& f : frames) {
    fe.process(f);
    for (const rt::RefineJob& job : fe.takeRefineJobs()) {
      const std::vector<float> before = roiDepthErrors(fe.map(), job);
      PhaseClock clock;
      const rt::RefineOutcome o =
          rt::runRefineJob(job, params.refine.implicit, rt::RefineBudget::kIterationsAndTime, &clock);
      for (size_t i = 0; i < clock.ms.size(); ++i) out.phase_ms[i] += clock.ms[i];
      out.job_cpu_ms.push_back(clock.inside());
      out.all_iterations += o.result.stats.iterations;
      fe.applyRefinement(o);
      out.depth.add(before, roiDepthErrors(fe.map(), job));
      const auto& st = o.result.stats;
      ++out.jobs;
      out.converged += st.converged;
      out.out_of_time += o.out_of_time;
      out.job_ms.push_back(o.setup_ms + o.train_ms + o.result_ms);
      out.setup_ms.push_back(o.setup_ms);
      if (st.iterations > 0) out.iteration_ms.push_back(o.train_ms / st.iterations);
      out.iterations.push_back(st.iterations);
      out.rays.push_back(static_cast<double>(st.rays - st.free_space_rays));
      out.free_rays.push_back(static_cast<double>(st.free_space_rays));
      out.memory_mb.push_back(static_cast<double>(st.memory_bytes) / (1 << 20));
      if (!o.result.patch.entries.empty()) out.boxes.push_back(job.roi.box_world);
    }
    if (++done % 40 == 0)
      std::fprintf(stderr, "  hybrid: %zu of %zu frames, %zu jobs\n", done, frames.size(), out.jobs);
  }
  out.hybrid_s = std::chrono::duration<double>(Clock::now() - t0).count();
  out.hybrid_mesh = alg::extractMesh(fe.map(), mp);
  out.detail_mesh = fe.mesh(mp);
  out.details = fe.details().size();
  out.poses = fe.trajectory();
  return out;
}

void printJobs(const HybridRun& r) {
  auto mean = [](const std::vector<double>& v) {
    double sum = 0;
    for (double e : v) sum += e;
    return v.empty() ? 0.0 : 1000.0 * sum / static_cast<double>(v.size());
  };
  const DepthL1& d = r.depth;
  auto share = [&](size_t n) {
    return d.pixels ? 100.0 * static_cast<double>(n) / static_cast<double>(d.pixels) : 0.0;
  };
  std::printf(
      "  jobs: %zu (%zu converged early, %zu stopped by the time budget); per job median %.0f ms (setup %.1f ms), "
      "%.0f iterations, per iteration median %.2f ms; memory per ROI median %.1f MiB, max %.1f MiB\n",
      r.jobs, r.converged, r.out_of_time, median(r.job_ms), median(r.setup_ms), median(r.iterations),
      median(r.iteration_ms), median(r.memory_mb),
      r.memory_mb.empty() ? 0.0 : *std::max_element(r.memory_mb.begin(), r.memory_mb.end()));
  std::printf("  rays per job median: %.0f landing in the ROI, %.0f crossing it to a surface beyond\n", median(r.rays),
              median(r.free_rays));
  double all = 0;
  for (size_t i = 1; i < r.phase_ms.size(); ++i) all += r.phase_ms[i];
  std::printf("  CPU per job median %.0f ms (after setup); where it goes, share and ms per iteration:",
              median(r.job_cpu_ms));
  for (size_t i = 1; i < r.phase_ms.size(); ++i) {
    std::printf(" %s %.0f%% %.2f", alg::refinePhaseName(static_cast<alg::RefinePhase>(i)),
                all > 0 ? 100.0 * r.phase_ms[i] / all : 0.0,
                r.all_iterations > 0 ? r.phase_ms[i] / r.all_iterations : 0.0);
  }
  std::printf("\n");
  std::printf(
      "  map rendering vs input depth inside each job's ROI, before -> after its write-back, where both render: "
      "median %.2f -> %.2f mm, mean %.2f -> %.2f mm; no surface rendered for %.1f%% -> %.1f%% of the pixels; "
      "the pixels it made render: median %.2f mm, mean %.2f mm\n",
      1000 * median(d.before_m), 1000 * median(d.after_m), mean(d.before_m), mean(d.after_m), share(d.missing_before),
      share(d.missing_after), 1000 * median(d.filled_m), mean(d.filled_m));
}

}  // namespace

// One quality-room case: the scene at `scale`, mapped at `voxel` twice.
void benchRoom(const drv::SyntheticScene& scene, const test::BenchSequence& seq, float scale, double voxel,
               const rt::FrontendParams& base) {
  const std::vector<RgbdFrame>& frames = seq.frames;
  const Trajectory& gt = seq.ground_truth;
  const alg::PinholeCamera& cam = seq.camera;
  const alg::TriangleMesh gt_mesh = scene.mesh();
  alg::MeshMetricsParams mp;
  mp.point_to_point = false;
  // Ground truth counts as observed where the synthetic sensor measured it:
  // in view, and not at the grazing angles it returns no depth for.
  const alg::ObservedBy observed{cam, gt, 4.0, drv::SyntheticParams{}.grazing_cos};
  rt::FrontendParams params = base;
  params.tsdf.voxel_size_m = voxel;
  params.tsdf.truncation_m = 4 * voxel;
  const std::string name =
      scale == 1.0f ? std::string("quality room") : fmt::format("quality room at {:g} size", scale);
  std::fprintf(stderr, "%s, %.0f cm voxels ...\n", name.c_str(), voxel * 100);
  const HybridRun r = mapTwice(frames, cam, gt, params);
  const auto whole_t = alg::computeMeshMetrics(r.tsdf_mesh, gt_mesh, mp, &observed).point_to_surface;
  const auto whole_h = alg::computeMeshMetrics(r.hybrid_mesh, gt_mesh, mp, &observed).point_to_surface;
  const Scores in_t = insideBoxes(r.tsdf_mesh, gt_mesh, r.boxes, observed, mp);
  const Scores in_h = insideBoxes(r.hybrid_mesh, gt_mesh, r.boxes, observed, mp);
  const auto whole_d = alg::computeMeshMetrics(r.detail_mesh, gt_mesh, mp, &observed).point_to_surface;
  const Scores in_d = insideBoxes(r.detail_mesh, gt_mesh, r.boxes, observed, mp);
  std::printf("%s, %zu frames, %.0f cm voxels: mapping %.1f s TSDF only, %.1f s hybrid (jobs inline, one core)\n",
              name.c_str(), frames.size(), voxel * 100, r.tsdf_s, r.hybrid_s);
  std::printf("  mesh @1cm            precision  recall     F1\n");
  std::printf("  whole scene  TSDF     %6.1f%%  %6.1f%%  %6.1f%%\n", 100 * whole_t.precision_fine,
              100 * whole_t.recall_fine, 100 * whole_t.f1_fine);
  std::printf("  whole scene  hybrid   %6.1f%%  %6.1f%%  %6.1f%%   (F1 %+.1f points; target: never worse)\n",
              100 * whole_h.precision_fine, 100 * whole_h.recall_fine, 100 * whole_h.f1_fine,
              100 * (whole_h.f1_fine - whole_t.f1_fine));
  std::printf("  whole scene  +detail  %6.1f%%  %6.1f%%  %6.1f%%   (F1 %+.1f points)\n", 100 * whole_d.precision_fine,
              100 * whole_d.recall_fine, 100 * whole_d.f1_fine, 100 * (whole_d.f1_fine - whole_t.f1_fine));
  std::printf("  in %3zu ROIs  TSDF     %6.1f%%  %6.1f%%  %6.1f%%\n", r.boxes.size(), 100 * in_t.precision,
              100 * in_t.recall, 100 * in_t.f1);
  std::printf("  in %3zu ROIs  hybrid   %6.1f%%  %6.1f%%  %6.1f%%   (F1 %+.1f points; target: >= +10)\n",
              r.boxes.size(), 100 * in_h.precision, 100 * in_h.recall, 100 * in_h.f1, 100 * (in_h.f1 - in_t.f1));
  std::printf("  in %3zu ROIs  +detail  %6.1f%%  %6.1f%%  %6.1f%%   (F1 %+.1f points)\n", r.boxes.size(),
              100 * in_d.precision, 100 * in_d.recall, 100 * in_d.f1, 100 * (in_d.f1 - in_t.f1));
  printJobs(r);
  std::printf("  precision @1cm inside the ROIs per region kind (share of the ROI surface):\n");
  const alg::TriangleBvh gt_bvh(gt_mesh);
  precisionByKind("TSDF", r.tsdf_mesh, gt_bvh, scene, r.boxes, static_cast<float>(voxel));
  precisionByKind("hybrid", r.hybrid_mesh, gt_bvh, scene, r.boxes, static_cast<float>(voxel));
  precisionByKind("+detail", r.detail_mesh, gt_bvh, scene, r.boxes, static_cast<float>(voxel));
  std::printf("  recall @1cm inside the ROIs per region kind (share of the observed ground truth there):\n");
  recallByKind("TSDF", r.tsdf_mesh, gt_mesh, observed, scene, r.boxes, static_cast<float>(voxel));
  recallByKind("hybrid", r.hybrid_mesh, gt_mesh, observed, scene, r.boxes, static_cast<float>(voxel));
  std::printf("  detail layer: %zu regions kept at the end\n", r.details);
}

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // results as they come, also into a file
  // A configuration's parameters (defaults without one); voxel size and
  // truncation are the benchmark's.
  rt::FrontendParams base;
  base.refine.implicit.detail_min_share = 0.5;  // the "+detail" mesh; a configuration file decides for itself
  if (argc > 3) {
    auto cfg = rt::loadConfig(argv[3]);
    if (!cfg) {
      std::fprintf(stderr, "%s\n", cfg.message().c_str());
      return 2;
    }
    base = rt::frontendParams(*cfg);
  }
  // The cases: (scene scale, voxel size). By default the full-size room at
  // 2 cm and 1 cm, and the half-size room at 1 cm (its rods and edges are
  // as thin against 1 cm voxels as the full-size room's against 2 cm).
  std::vector<std::pair<float, double>> cases{{1.0f, 0.02}, {0.5f, 0.01}, {1.0f, 0.01}};
  const char* env_scale = std::getenv("HXMAP_BENCH_SCALE");
  const char* env_voxels = std::getenv("HXMAP_BENCH_VOXELS");
  const std::string dir = argc > 1 ? argv[1] : "";
  if (env_scale != nullptr || env_voxels != nullptr || (!dir.empty() && dir != "-")) {
    // One scale (a folder holds one); the voxel sizes of the cases at that
    // scale, or the one asked for.
    const float scale = test::benchSceneScale();
    std::vector<std::pair<float, double>> chosen;
    if (env_voxels != nullptr) {
      chosen.emplace_back(scale, std::atof(env_voxels));
    } else {
      for (const auto& c : cases) {
        if (c.first == scale) chosen.push_back(c);
      }
      if (chosen.empty()) chosen.emplace_back(scale, 0.02 * scale);
    }
    cases = chosen;
  }
  test::BenchSequence seq;
  float loaded_scale = 0.0f;
  for (const auto& [scale, voxel] : cases) {
    if (scale != loaded_scale) {
      if (!test::loadOrRenderQualityRoom(dir, seq, "inspect", scale)) return 2;
      loaded_scale = scale;
    }
    benchRoom(test::benchQualityRoom(scale), seq, scale, voxel, base);
  }

  // Replica slice: depth L1 inside ROIs before and after write-back.
  if (argc > 2 && std::string(argv[2]) == "-") return 0;
  const std::string replica = argc > 2 ? argv[2] : std::string(HXMAP_SHARED_DATA) + "/replica/room0_first20/room0";
  auto ds = drv::Dataset::open(replica);
  if (!ds) {
    std::fprintf(stderr, "%s\n", ds.message().c_str());
    return 2;
  }
  std::vector<RgbdFrame> rframes;
  for (size_t i = 0; i < (*ds)->size(); ++i) {
    auto f = (*ds)->load(i);
    if (f) rframes.push_back(std::move(*f));
  }
  std::fprintf(stderr, "Replica slice ...\n");
  const HybridRun rr = mapTwice(rframes, (*ds)->camera(), (*ds)->groundTruth(), base);
  std::printf("Replica slice (%zu frames, %dx%d, 2 cm voxels):\n", rframes.size(), (*ds)->camera().width,
              (*ds)->camera().height);
  printJobs(rr);
  return 0;
}
