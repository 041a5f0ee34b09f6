// Tracking benchmark: every real sequence under ../shared/data (and any
// folder given on the command line) and the synthetic sequences that stress
// tracking (fast hand-held, the same with a hand-held color camera, a 1.5 s
// blackout, every other frame dropped,
// and the plain orbit they compare with), each run by hxmap's frontend and,
// on the same frames in the same run, by OpenCV's ICPOdometry and
// RgbdICPOdometry frame to frame. Prints per sequence and method: frames
// tracked / degraded / lost / relocalized, ATE, RPE per second (translation
// and rotation) and ms per frame (median, one core). Asserts nothing.
//
//   bench_tracking [--config FILE] [--no-synthetic] [--only NAME] [DATASET_DIR...]
//
// The frontend runs with the given configuration (default: the built-in
// defaults) with refinement off: refinement does not move poses, and this
// is a tracking benchmark. Synthetic sequences are rendered into a
// temporary folder first (about a minute).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <unistd.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/rgbd.hpp>

#include "bench_stats.hpp"
#include "commands.hpp"
#include "hxmap/config/config.hpp"
#include "hxmap/dataset/dataset.hpp"
#include "hxmap/dataset/synthetic.hpp"
#include "hxmap/eval/trajectory_metrics.hpp"
#include "hxmap/frontend/frontend.hpp"

using namespace hxmap;
namespace fs = std::filesystem;

namespace {

using bench::Clock;
using bench::median;
using bench::ms;

struct Row {
  std::string method;
  size_t tracked = 0, degraded = 0, lost = 0, relocalized = 0;
  Trajectory trajectory;
  std::vector<double> frame_ms;
  std::string extra;
};

// OpenCV's frame-to-frame odometry: pose_k = pose_{k-1} * Rt^-1 (Rt maps
// the previous frame's points into the current one); a failed frame keeps
// the previous pose and the next is matched against the last good frame.
class OpenCvOdometry {
 public:
  OpenCvOdometry(const char* name, cv::Ptr<cv::rgbd::Odometry> odometry) : odometry_(std::move(odometry)) {
    row_.method = name;
  }
  void add(const RgbdFrame& f, const cv::Mat& gray, const Eigen::Isometry3d& T_first) {
    const auto t0 = Clock::now();
    cv::Mat mask = f.depth > 0;
    if (prev_depth_.empty()) {
      pose_ = T_first;
      ++row_.tracked;
    } else {
      cv::Mat Rt;
      const bool ok = odometry_->compute(prev_gray_, prev_depth_, prev_mask_, gray, f.depth, mask, Rt);
      if (ok && !Rt.empty()) {
        Eigen::Matrix4d M;
        for (int r = 0; r < 4; ++r) {
          for (int c = 0; c < 4; ++c) M(r, c) = Rt.at<double>(r, c);
        }
        Eigen::Isometry3d T(M);
        pose_ = pose_ * T.inverse();
        ++row_.tracked;
      } else {
        ++row_.lost;
      }
    }
    row_.frame_ms.push_back(ms(t0, Clock::now()));
    row_.trajectory.push_back({f.stamp_ns, pose_});
    prev_gray_ = gray;
    prev_depth_ = f.depth;
    prev_mask_ = mask;
  }
  const Row& row() const { return row_; }

 private:
  cv::Ptr<cv::rgbd::Odometry> odometry_;
  cv::Mat prev_gray_, prev_depth_, prev_mask_;
  Eigen::Isometry3d pose_ = Eigen::Isometry3d::Identity();
  Row row_;
};

void printRow(const std::string& sequence, const Row& r, const Trajectory& gt) {
  const alg::AteResult ate = alg::computeAte(r.trajectory, gt);
  const alg::RpeResult rpe = alg::computeRpe(r.trajectory, gt, 1'000'000'000);
  std::printf("%-28s %-16s %5zu %5zu %5zu %5zu %8.3f %8.2f %8.2f %7.2f  %s\n", sequence.c_str(), r.method.c_str(),
              r.tracked, r.degraded, r.lost, r.relocalized, ate.pairs ? ate.rmse_m * 100 : -1.0,
              rpe.pairs ? rpe.trans_rmse_m * 100 : -1.0, rpe.pairs ? rpe.rot_rmse_deg : -1.0, median(r.frame_ms),
              r.extra.c_str());
  std::fflush(stdout);
}

int runSequence(const std::string& name, const std::string& dir, const rt::HxmapConfig& config) {
  auto opened = drv::Dataset::open(dir);
  if (!opened) {
    std::fprintf(stderr, "%s\n", opened.message().c_str());
    return 1;
  }
  const drv::Dataset& d = **opened;
  const Trajectory& gt = d.groundTruth();
  if (gt.empty()) {
    std::fprintf(stderr, "%s: no ground truth, skipped\n", dir.c_str());
    return 0;
  }
  const alg::PinholeCamera& cam = d.camera();
  rt::FrontendParams fp = rt::frontendParams(config);
  fp.refine.enabled = false;
  rt::Frontend frontend(cam, fp);
  Eigen::Isometry3d T0 = Eigen::Isometry3d::Identity();
  alg::interpolatePose(gt, d.stamp(0), 200'000'000, T0);
  frontend.setInitialPose(T0);
  const cv::Mat K = (cv::Mat_<double>(3, 3) << cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
  OpenCvOdometry icp("cv ICPOdometry", cv::rgbd::ICPOdometry::create(K));
  OpenCvOdometry rgbd_icp("cv RgbdICPOdom.", cv::rgbd::RgbdICPOdometry::create(K));
  Row hx;
  hx.method = "hxmap";
  for (size_t i = 0; i < d.size(); ++i) {
    auto f = d.load(i);
    if (!f) {
      std::fprintf(stderr, "%s\n", f.message().c_str());
      return 1;
    }
    const auto t0 = Clock::now();
    const rt::FrameResult r = frontend.process(*f);
    hx.frame_ms.push_back(ms(t0, Clock::now()));
    cv::Mat gray;
    cv::cvtColor(f->rgb, gray, cv::COLOR_RGB2GRAY);
    icp.add(*f, gray, T0);
    rgbd_icp.add(*f, gray, T0);
    if (i % 100 == 99) std::fprintf(stderr, "  %s: %zu / %zu frames\n", name.c_str(), i + 1, d.size());
  }
  const alg::TrackingCounts& c = frontend.trackingCounts();
  hx.tracked = c.tracked;
  hx.degraded = c.degraded;
  hx.lost = frontend.lostFrames();
  hx.relocalized = c.relocalized;
  hx.trajectory = frontend.trajectory();
  const rt::TrackingCounters t = frontend.trackingCounters();
  char extra[200];
  std::snprintf(extra, sizeof extra, "reloc %llu tries, %.1f ms each; kf features %.1f ms",
                static_cast<unsigned long long>(t.relocalization_attempts),
                t.relocalization_attempts ? t.relocalization_ms / static_cast<double>(t.relocalization_attempts) : 0.0,
                frontend.keyframes() ? t.keyframe_features_ms / static_cast<double>(frontend.keyframes()) : 0.0);
  hx.extra = extra;
  printRow(name, hx, gt);
  printRow(name, icp.row(), gt);
  printRow(name, rgbd_icp.row(), gt);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  cv::setNumThreads(0);  // one core for every method
  rt::keepHeapBetweenFrames();
  std::string config_path, only;
  bool synthetic = true;
  std::vector<std::pair<std::string, std::string>> sequences;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--config" && i + 1 < argc) {
      config_path = argv[++i];
    } else if (a == "--only" && i + 1 < argc) {
      only = argv[++i];
    } else if (a == "--no-synthetic") {
      synthetic = false;
    } else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "usage: bench_tracking [--config FILE] [--no-synthetic] [--only NAME] [DATASET_DIR...]\n");
      return 2;
    } else {
      sequences.emplace_back(fs::path(a).filename().string(), a);
    }
  }
  auto config = config_path.empty() ? Expected<rt::HxmapConfig>(rt::HxmapConfig{}) : rt::loadConfig(config_path);
  if (!config) {
    std::fprintf(stderr, "%s\n", config.message().c_str());
    return 2;
  }
  if (sequences.empty()) {
    const std::string shared = HXMAP_SHARED_DATA;
    for (const char* s : {"tum/rgbd_dataset_freiburg1_xyz", "tum/rgbd_dataset_freiburg1_xyz_first40",
                          "replica/room0_first20/room0"}) {
      if (fs::exists(shared + "/" + s)) sequences.emplace_back(fs::path(s).filename().string(), shared + "/" + s);
    }
  }
  if (synthetic) {
    const fs::path root = fs::temp_directory_path() / ("hxmap_bench_tracking_" + std::to_string(getpid()));
    struct Synth {
      const char* name;
      const char* trajectory;
      double blackout_start_s, blackout_s;
      int drop_every;
      bool handheld_camera;  // the color camera of `hxmap synth --handheld-camera`
    };
    for (const Synth& s : {Synth{"synthetic orbit", "orbit", 0, 0, 0, false},
                           Synth{"synthetic fast", "fast", 0, 0, 0, false},
                           Synth{"synthetic fast, hand-held", "fast", 0, 0, 0, true},
                           Synth{"synthetic blackout", "orbit", 4.0, 1.5, 0, false},
                           Synth{"synthetic drop 1 of 2", "orbit", 0, 0, 2, false}}) {
      if (!only.empty() && only != s.name) continue;
      drv::SyntheticParams p;
      p.frames = 300;
      p.trajectory = s.trajectory;
      p.blackout_start_s = s.blackout_start_s;
      p.blackout_s = s.blackout_s;
      p.drop_every = s.drop_every;
      if (s.handheld_camera) {
        p.color_delay_s = 0.012;
        p.rolling_shutter_s = 0.03;
        p.exposure_s = 0.02;
        p.gain_variation = 0.1;
      }
      const std::string dir = (root / s.trajectory).string() + std::to_string(sequences.size());
      std::fprintf(stderr, "rendering %s into %s\n", s.name, dir.c_str());
      if (auto st = drv::writeSyntheticSequence(dir, drv::SyntheticScene::room(), p); !st) {
        std::fprintf(stderr, "%s\n", st.message().c_str());
        return 1;
      }
      const drv::TrajectorySpeeds v = drv::trajectorySpeeds(drv::syntheticTrajectory(p));
      std::fprintf(stderr, "  %s: peak %.2f m/s, %.0f deg/s\n", s.name, v.max_linear_mps, v.max_angular_dps);
      sequences.emplace_back(s.name, dir);
    }
  }
  std::printf("%-28s %-16s %5s %5s %5s %5s %8s %8s %8s %7s\n", "sequence", "method", "track", "degr", "lost", "reloc",
              "ATE cm", "RPE cm/s", "RPE d/s", "ms/frm");
  int status = 0;
  for (const auto& [name, dir] : sequences) {
    if (!only.empty() && only != name) continue;
    status |= runSequence(name, dir, *config);
  }
  return status;
}
