#include "hxmap/frontend/frontend.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>

#include <malloc.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "hxmap/feedback/residuals.hpp"
#include "hxmap/geometry/se3.hpp"
#include "hxmap/tsdf/integrate.hpp"
#include "memory_budget.hpp"

namespace hxmap::rt {

namespace {
/// The world box of a camera-frame vertex map's valid points (z > 0) at
/// T_world_cam, widened by `margin_m`; empty when none is valid.
Eigen::AlignedBox3f viewBox(const cv::Mat& vertex, const Eigen::Isometry3f& T_world_cam, float margin_m) {
  Eigen::AlignedBox3f box;
  for (int v = 0; v < vertex.rows; ++v) {
    const cv::Vec3f* row = vertex.ptr<cv::Vec3f>(v);
    for (int u = 0; u < vertex.cols; ++u) {
      if (row[u][2] > 0.0f) box.extend(T_world_cam * Eigen::Vector3f(row[u][0], row[u][1], row[u][2]));
    }
  }
  if (!box.isEmpty()) {
    box.min().array() -= margin_m;
    box.max().array() += margin_m;
  }
  return box;
}

class StageTimer {
 public:
  explicit StageTimer(double& out_ms) : out_(out_ms), start_(std::chrono::steady_clock::now()) {}
  ~StageTimer() { out_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count(); }
  StageTimer(const StageTimer&) = delete;
  StageTimer& operator=(const StageTimer&) = delete;

 private:
  double& out_;
  std::chrono::steady_clock::time_point start_;
};
}  // namespace

void keepHeapBetweenFrames() {
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 512 << 20);
}

Frontend::Frontend(const alg::PinholeCamera& camera, const FrontendParams& params, ParallelFor parallel)
    : camera_(camera),
      params_(params),
      parallel_(std::move(parallel)),
      map_(params.tsdf),
      keyframe_db_(params.relocalization),
      quality_(params.quality) {
  // One noise model for preprocessing and tracking's gates.
  params_.tracking.noise_sigma_a_m = params_.preprocess.noise_sigma_a_m;
  params_.tracking.noise_sigma_b_per_m = params_.preprocess.noise_sigma_b_per_m;
  makeLoopCloser();
}

void Frontend::makeLoopCloser() {
  if (params_.loop_closure.enabled && params_.relocalization.enabled) {
    loop_closer_ = std::make_unique<LoopCloser>(
        LoopCloserParams{params_.loop_closure, params_.relocalization, params_.tracking, params_.tsdf, params_.raycast},
        camera_, parallel_);
    loop_closer_->setBlockBacking(loop_backing_, loopBudgetBytes());
  }
}

void Frontend::resumeMap(alg::TsdfMap map, alg::KeyframeDatabase keyframes) {
  map_ = std::move(map);
  keyframe_db_ = std::move(keyframes);
  for (const auto& k : keyframe_db_.keyframes()) keyframe_id_base_ = std::max(keyframe_id_base_, k.id + 1);
  initialized_ = true;  // lost until relocalized: no model, no previous frame
  resuming_ = true;
  // DESIGN: loop closure goes on in the saved map: its keyframes are fixed
  // nodes of the graph (this run does not move what the saved map holds),
  // and a closure fuses this run's keyframes onto a copy of the saved map
  // at their new poses. Under a memory budget it stays off: that copy
  // would be held in memory beside the map.
  if (loop_closer_ && budgetBytes() > 0) {
    spdlog::info("loop closure is off for a run that continues a saved map under a memory budget");
    loop_closer_.reset();
  }
  if (loop_closer_) loop_closer_->seed(map_, keyframe_db_);
}

size_t Frontend::budgetBytes() const { return static_cast<size_t>(params_.tsdf.max_resident_mib * (1 << 20)); }

void Frontend::bringBack(const std::vector<uint64_t>& keys) {
  const uint64_t lost_before = map_.blocksLostInBacking();
  for (const uint64_t k : keys) map_.findOrAllocate(alg::unpackBlockKey(k));
  memory_counters_.lost += map_.blocksLostInBacking() - lost_before;
  countTakenBack();
}

void Frontend::countTakenBack() {
  // The map's own count starts over when a loop closure replaces it.
  const uint64_t taken = map_.blocksTakenBack();
  memory_counters_.taken_back += taken >= taken_back_seen_ ? taken - taken_back_seen_ : taken;
  taken_back_seen_ = taken;
}

void Frontend::prefetch(const Eigen::Isometry3d& T_world_predicted) {
  if (map_.blocksElsewhere().empty()) return;
  const auto t0 = std::chrono::steady_clock::now();
  const Eigen::Isometry3f T_cam_world = T_world_predicted.inverse().cast<float>();
  std::vector<std::pair<float, uint64_t>> wanted =
      budget::blocksOutInView(map_, T_cam_world, camera_, static_cast<float>(params_.tsdf.max_integration_depth_m));
  // Nearest first, as many as fit in the budget (a view that holds more
  // than the budget gets its nearest part) and the per-frame cap.
  const size_t budget = budgetBytes(), resident = map_.memory().bytes;
  const size_t room = resident < budget ? (budget - resident) / sizeof(alg::VoxelBlock) : 0;
  const size_t cap = std::min(room, static_cast<size_t>(std::max(0, params_.max_prefetch_per_frame)));
  if (wanted.size() > cap) {
    std::nth_element(wanted.begin(), wanted.begin() + static_cast<std::ptrdiff_t>(cap), wanted.end());
    memory_counters_.prefetch_capped += wanted.size() - cap;
    wanted.resize(cap);
  }
  std::vector<uint64_t> keys;
  keys.reserve(wanted.size());
  if (params_.wait_for_blocks) {
    for (const auto& [z, k] : wanted) keys.push_back(k);
  } else {
    // The backing reads the whole view ahead on its own thread; what it
    // has read comes back now, the rest in a later frame.
    std::vector<alg::BlockKey> hint;
    hint.reserve(wanted.size());
    for (const auto& [z, k] : wanted) hint.push_back(alg::unpackBlockKey(k));
    backing_->prefetch(hint);
    for (size_t i = 0; i < hint.size(); ++i) {
      if (backing_->ready(hint[i])) keys.push_back(wanted[i].second);
    }
    memory_counters_.prefetch_not_ready += hint.size() - keys.size();
  }
  bringBack(keys);
  memory_counters_.prefetched += keys.size();
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  memory_counters_.prefetch_ms_total += ms;
  memory_counters_.prefetch_ms_max = std::max(memory_counters_.prefetch_ms_max, ms);
}

void Frontend::enforceBudget(const Eigen::Isometry3d& T_world_cam) {
  const size_t budget = budgetBytes(), resident = map_.memory().bytes;
  memory_counters_.resident_bytes_max = std::max(memory_counters_.resident_bytes_max, resident);
  countTakenBack();  // fusion's too
  // DESIGN: from 90 % of the budget, down to 80 %, at most
  // max_evictions_per_frame blocks a frame, and always as many as it takes
  // to end the frame within the budget. A block moved out costs the
  // frontend a copy into the store's queue (about 5 us; the store
  // compresses and writes it on its own thread). The cap alone (96 blocks)
  // let a 1 cm map outgrow a 256 MiB budget by 44 % where the camera saw
  // more new surface a frame than that. After a loop closure replaced the
  // map, the floor moves thousands of blocks in one frame: a few ms at
  // this cost (33 ms when this thread compressed them).
  const size_t count = budget::blocksToMoveOut(
      resident, budget, static_cast<size_t>(std::max(0, params_.max_evictions_per_frame)), map_.blockCount());
  if (count == 0) return;
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<int32_t> victims =
      budget::farthestBlocks(map_, T_world_cam.inverse().cast<float>(), camera_,
                             static_cast<float>(params_.tsdf.max_integration_depth_m), count);
  memory_counters_.lost += map_.removeBlocks(std::move(victims));
  if (map_.memory().bytes > budget) ++memory_counters_.frames_over_budget;
  memory_counters_.evicted += count;
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  memory_counters_.evict_ms_total += ms;
  memory_counters_.evict_ms_max = std::max(memory_counters_.evict_ms_max, ms);
}

void Frontend::restoreEvicted() {
  std::vector<uint64_t> keys;
  keys.reserve(map_.blocksElsewhere().size());
  map_.blocksElsewhere().forEach([&](const alg::BlockKey& k) { keys.push_back(alg::packBlockKey(k)); });
  bringBack(keys);
}

void Frontend::checkResume(const FrameResult& r) {
  if (r.tracked) {
    resuming_ = false;
    resumed_at_frame_ = frames_seen_ - 1;
    spdlog::info("relocalized in the saved map at frame {}", resumed_at_frame_);
    return;
  }
  if (frames_seen_ < std::max(1, params_.resume_relocalize_frames)) return;
  resuming_ = false;
  if (!params_.resume_new_map_otherwise) {
    spdlog::error("not relocalized in the saved map within {} frames ({})", frames_seen_, r.failure);
    resume_failed_ = true;
    return;
  }
  spdlog::warn("not relocalized in the saved map within {} frames: a new map starts here", frames_seen_);
  map_ = alg::TsdfMap(params_.tsdf);
  keyframe_db_ = alg::KeyframeDatabase(params_.relocalization);
  keyframe_index_.clear();
  keyframe_id_base_ = 0;
  initialized_ = false;
  lost_since_.reset();
  resume_abandoned_ = true;
  makeLoopCloser();
}

void Frontend::warmUp() {
  FrontendParams p = params_;
  p.quality_enabled = false;
  p.refine.enabled = false;
  p.feedback.enabled = false;
  Frontend scratch(camera_, p, parallel_);
  RgbdFrame f;
  f.depth = cv::Mat(camera_.height, camera_.width, CV_32F);
  f.rgb = cv::Mat(camera_.height, camera_.width, CV_8UC3);
  for (int i = 0; i < 4; ++i) {
    // A wall 1.5 m away, tilted, with a checker texture; it shifts by a
    // few millimeters per frame so that tracking has work to do.
    for (int v = 0; v < camera_.height; ++v) {
      float* d = f.depth.ptr<float>(v);
      auto* c = f.rgb.ptr<cv::Vec3b>(v);
      for (int u = 0; u < camera_.width; ++u) {
        d[u] = 1.5f + 0.0004f * static_cast<float>(u) + 0.002f * static_cast<float>(i);
        const uint8_t k = (((u + 2 * i) / 16 + v / 16) & 1) ? 200 : 60;
        c[u] = cv::Vec3b(k, k, k);
      }
    }
    f.stamp_ns = static_cast<int64_t>(i) * 33'000'000;
    f.seq = static_cast<uint32_t>(i);
    scratch.process(f);
  }
}

FrameResult Frontend::process(const RgbdFrame& frame, const Eigen::Isometry3d* T_given) {
  FrameResult r;
  ++frames_seen_;
  // A pose is the depth camera's (tracking aligns depth), so it carries
  // the depth image's stamp (the color stamp cost 1.17 -> 1.28 cm ATE on
  // the whole TUM fr1/xyz, whose images are up to 17 ms apart).
  r.stamp_ns = frame.depth_stamp_ns > 0 ? frame.depth_stamp_ns : frame.stamp_ns;
  r.T_world_odom = T_world_odom_;

  // 1. Preprocess: depth in meters, denoise, pyramid, normals, confidence.
  alg::PreprocessedFrame pre;
  {
    StageTimer t(r.stage_ms[kPreprocess]);
    pre = alg::preprocessFrame(frame, camera_, params_.preprocess, parallel_);
  }
  if (!initialized_ && !canStartMap(pre, r)) return r;

  // 2. Track: against the model, else frame to frame, else lost.
  alg::IcpResult icp;
  Eigen::Isometry3d T_world_cam = T_given ? *T_given : T_initial_;
  const alg::TrackingDecision decision = locate(pre, T_given, icp, T_world_cam, r);
  if (!r.tracked) {
    keepLost(r);
    if (resuming_) checkResume(r);
    return r;
  }
  if (resuming_) checkResume(r);
  if (lost_since_) fillLostPoses(r.stamp_ns, T_world_cam);
  if (!params_.odometry_bias.isZero(0)) T_world_cam = T_world_cam * alg::expSE3(params_.odometry_bias);
  if (!decision.fuse) {
    followWithoutFusing(pre, T_world_cam, decision, r);
    return r;
  }

  // 3. Integrate the range-gated depth with per-pixel confidence.
  fuse(pre, T_world_cam, r);
  if (backing_ && params_.tsdf.max_resident_mib > 0) {
    // Under a memory budget: what the next frame will see comes back (the
    // model rendered below then holds it), and the farthest blocks leave.
    StageTimer t(r.stage_ms[kIntegrate]);
    prefetch(velocity_valid_ ? T_world_cam * velocity_ : T_world_cam);
    enforceBudget(T_world_cam);
  }

  // 4. Raycast the model at the new pose for the next frame (the fused depth
  //    predicts where each ray meets the surface).
  {
    StageTimer t(r.stage_ms[kRaycast]);
    renderModel(last_frame_, T_last_);
  }
  trajectory_.push_back({r.stamp_ns, T_world_cam});

  // 5. Keyframes by motion and time (quality, refinement, feedback,
  //    keyframe database, loop closure).
  if (!initialized_ || alg::isNewKeyframe(T_last_kf_, T_world_cam, last_kf_ns_, r.stamp_ns, params_.tracking,
                                          last_kf_depth_m_, params_.tsdf.voxel_size_m)) {
    makeKeyframe(icp, T_world_cam, r);
  }
  initialized_ = true;
  return r;
}

bool Frontend::canStartMap(const alg::PreprocessedFrame& pre, FrameResult& r) {
  if (pre.valid_pixels >= minValidPixels()) return true;
  r.failure = "too little valid depth (" + std::to_string(pre.valid_pixels) + " pixels) to start the map";
  ++lost_frames_;
  r.T_world_cam = T_initial_;
  trajectory_.push_back({r.stamp_ns, r.T_world_cam});
  return false;
}

alg::TrackingDecision Frontend::locate(const alg::PreprocessedFrame& pre, const Eigen::Isometry3d* T_given,
                                       alg::IcpResult& icp, Eigen::Isometry3d& T_world_cam, FrameResult& r) {
  alg::TrackingDecision decision;
  if (!initialized_) {
    decision = state_machine_.start();
  } else if (T_given) {
    decision = state_machine_.given();
  } else {
    StageTimer t(r.stage_ms[kTrack]);
    decision = track(pre, icp, T_world_cam);
  }
  r.state = decision.state;
  r.pose_source = decision.source;
  r.tracked = decision.state != alg::TrackingState::kLost;
  r.failure = decision.reason;
  r.inliers = icp.inliers;
  r.rms_residual_m = icp.rms_residual_m;
  r.consistent_ratio = icp.consistent_ratio;
  return decision;
}

void Frontend::keepLost(FrameResult& r) {
  // Keep the map and the last pose; restart motion from rest.
  ++lost_frames_;
  velocity_.setIdentity();
  velocity_valid_ = false;  // the next pose is not one frame after the last
  velocity_dt_s_ = 0;
  r.T_world_cam = T_last_;
  if (!lost_since_) lost_since_ = trajectory_.size();
  trajectory_.push_back({r.stamp_ns, r.T_world_cam});
}

void Frontend::followWithoutFusing(const alg::PreprocessedFrame& pre, const Eigen::Isometry3d& T_world_cam,
                                   const alg::TrackingDecision& decision, FrameResult& r) {
  // The next frame is tracked from here, against the model rendered here
  // and this frame.
  followPose(T_world_cam, pre);
  r.T_world_cam = T_world_cam;
  if (decision.source != alg::PoseSource::kRelocalization) {  // relocalization rendered it already
    StageTimer t(r.stage_ms[kRaycast]);
    renderModel(previous_frame_, T_world_cam);
  }
  trajectory_.push_back({r.stamp_ns, T_world_cam});
}

void Frontend::fuse(alg::PreprocessedFrame& pre, const Eigen::Isometry3d& T_world_cam, FrameResult& r) {
  {
    StageTimer t(r.stage_ms[kIntegrate]);
    alg::DepthObservation obs{pre.depth_m, pre.rgb, pre.levels[pre.finest].confidence, camera_,
                              T_world_cam.cast<float>()};
    alg::integrate(map_, obs, parallel_);
  }
  followPose(T_world_cam, pre);
  last_frame_ = std::move(pre);  // headers: previous_frame_ shares the buffers
  r.integrated = true;
  r.T_world_cam = T_world_cam;
}

void Frontend::makeKeyframe(const alg::IcpResult& icp, const Eigen::Isometry3d& T_world_kf, FrameResult& r) {
  const Eigen::Isometry3d T_previous_kf = T_last_kf_;
  const alg::PreprocessedFrame previous_kf = keyframe_reference_;  // headers
  const Eigen::Isometry3d T_previous_kf_color = T_keyframe_color_;
  r.keyframe = true;
  r.keyframe_id = keyframe_id_base_ + static_cast<uint32_t>(keyframes_);
  if (params_.feedback.enabled) {
    keepFeedbackKeyframe(r.keyframe_id, r.stamp_ns, initialized_ ? &icp : nullptr, T_last_kf_);
  }
  T_last_kf_ = T_world_kf;
  last_kf_ns_ = r.stamp_ns;
  keyframe_reference_ = last_frame_;
  T_keyframe_color_ = T_previous_color_;
  if (params_.tracking.keyframe_baseline_ratio > 0 && !last_frame_.levels.empty()) {
    last_kf_depth_m_ = alg::medianDepth(last_frame_.levels.back().depth);
  }
  ++keyframes_;
  if (params_.quality_enabled) {
    StageTimer t(r.stage_ms[kKeyframe]);
    scoreKeyframe(r);
    if (params_.refine.enabled) {
      keepKeyframeImages(r.keyframe_id);
      makeRefineJobs(r.keyframe_id);
    }
  }
  if (!params_.relocalization.enabled) return;
  keyframe_index_[r.keyframe_id] = trajectory_.size() - 1;  // this frame's entry
  // DESIGN: in real time a keyframe's ORB features (12-15 ms at 640x480)
  // are made on loop closure's thread: on the frontend's they were what
  // made it miss deadlines at 30 FPS (fr1/xyz: 40-53 misses, 1-3 without
  // them). Relocalization then matches the newest keyframe a few frames
  // later; offline the features come back before the next frame.
  double features_ms = 0;
  alg::FrameFeatures features;
  if (!describe_elsewhere_) {
    StageTimer t(features_ms);
    features = addToKeyframeDatabase(r.keyframe_id, last_frame_, T_world_kf);
  }
  r.stage_ms[kKeyframe] += features_ms;
  // Loop closure (or, in real time, only the features): a closure found
  // now moves this frame too.
  if (params_.loop_closure.enabled || describe_elsewhere_) {
    double loop_ms = 0;
    {
      StageTimer t(loop_ms);
      sendToLoopCloser(r.keyframe_id, std::move(features), previous_kf, T_previous_kf, T_previous_kf_color, T_world_kf);
    }
    r.stage_ms[kKeyframe] += loop_ms;
    r.T_world_cam = trajectory_.back().T_world_cam;
    r.T_world_odom = T_world_odom_;
  }
}

void Frontend::fillLostPoses(int64_t stamp_ns, const Eigen::Isometry3d& T_found) {
  // DESIGN: a lost frame reports the last pose while it is lost (nothing
  // better is known then); once tracking is back, the trajectory's lost
  // frames get poses interpolated by time between the poses either side
  // (linear in translation, spherical in rotation). Offline outputs (the
  // trajectory file) carry these; live outputs have already published.
  const size_t first = *lost_since_;
  lost_since_.reset();
  if (first == 0) {
    // Lost from the first frame (a resumed map not yet relocalized in):
    // nothing before to interpolate from; the found pose is the nearest known.
    for (StampedPose& p : trajectory_) p.T_world_cam = T_found;
    return;
  }
  if (first > trajectory_.size()) return;
  const StampedPose& a = trajectory_[first - 1];
  const Eigen::Quaterniond qa(a.T_world_cam.linear()), qb(T_found.linear());
  const double span = static_cast<double>(stamp_ns - a.stamp_ns);
  for (size_t i = first; i < trajectory_.size(); ++i) {
    const double s = span > 0 ? std::clamp(static_cast<double>(trajectory_[i].stamp_ns - a.stamp_ns) / span, 0.0, 1.0) : 1.0;
    Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
    T_world_cam.linear() = qa.slerp(s, qb).toRotationMatrix();
    T_world_cam.translation() = (1 - s) * a.T_world_cam.translation() + s * T_found.translation();
    trajectory_[i].T_world_cam = T_world_cam;
    ++tracking_counters_.interpolated_poses;
  }
}

void Frontend::followPose(const Eigen::Isometry3d& T_world_cam, const alg::PreprocessedFrame& pre) {
  if (initialized_ && velocity_valid_) {
    velocity_ = T_last_.inverse() * T_world_cam;
    velocity_dt_s_ = static_cast<double>(pre.depth_stamp_ns - previous_depth_ns_) * 1e-9;
  } else {
    velocity_.setIdentity();
    velocity_dt_s_ = 0;
  }
  velocity_valid_ = true;
  T_last_ = T_world_cam;
  previous_frame_ = pre;
  previous_depth_ns_ = pre.depth_stamp_ns;
  T_previous_ = T_world_cam;
  T_previous_color_ = T_world_cam * colorOffset(pre);
}

Eigen::Isometry3d Frontend::colorOffset(const alg::PreprocessedFrame& f) const {
  const double tau_s = static_cast<double>(f.stamp_ns - f.depth_stamp_ns) * 1e-9;
  if (tau_s == 0 || !(velocity_dt_s_ > 0)) return Eigen::Isometry3d::Identity();
  // The camera's motion over the color image's offset, at the last
  // frame-to-frame velocity (body frame, constant over one frame).
  return alg::expSE3(alg::logSE3(velocity_) * (tau_s / velocity_dt_s_));
}

double Frontend::photometricScale() const {
  const alg::TrackingParams& p = params_.tracking;
  if (!p.photometric_scale_from_residuals || p.photometric_scale_m <= 0 || photometric_ratios_.size() < 5) {
    return p.photometric_scale_m;
  }
  std::vector<double> r(photometric_ratios_.begin(), photometric_ratios_.end());
  std::nth_element(r.begin(), r.begin() + static_cast<std::ptrdiff_t>(r.size() / 2), r.end());
  return std::clamp(r[r.size() / 2], p.photometric_scale_m / 4, p.photometric_scale_m * 4);
}

int Frontend::minValidPixels() const {
  return std::max(params_.tracking.min_inliers, camera_.width * camera_.height / 100);
}

namespace {
// Better of two tracking results: usable over failed, fusable over degraded,
// then the larger share of associations within the noise gate.
bool betterTrack(const alg::IcpResult& a, const alg::IcpResult& b) {
  if (a.ok != b.ok) return a.ok;
  if (a.ok && a.degraded.empty() != b.degraded.empty()) return a.degraded.empty();
  return a.consistent_ratio * a.inliers > b.consistent_ratio * b.inliers;
}
}  // namespace

alg::TrackingDecision Frontend::track(const alg::PreprocessedFrame& pre, alg::IcpResult& icp,
                                      Eigen::Isometry3d& T_world_cam) {
  alg::TrackingAttempts attempts;
  attempts.enough_depth = pre.valid_pixels >= minValidPixels();
  if (!attempts.enough_depth) {
    alg::TrackingDecision d = state_machine_.update(attempts);
    d.reason = "too little valid depth (" + std::to_string(pre.valid_pixels) + " pixels)";
    return d;
  }
  const bool kf_ref = params_.tracking.photometric_keyframe_reference && !keyframe_reference_.levels.empty() &&
                      state_machine_.state() == alg::TrackingState::kTracked;
  alg::PhotometricReference reference{kf_ref ? &keyframe_reference_ : &previous_frame_,
                                      kf_ref ? T_keyframe_color_ : T_previous_color_, colorOffset(pre)};
  const double interval_s = static_cast<double>(pre.depth_stamp_ns - previous_frame_.depth_stamp_ns) * 1e-9;
  if (params_.tracking.color_offset_from_motion && pre.stamp_ns != pre.depth_stamp_ns &&
      !previous_frame_.levels.empty() && interval_s > 0 && state_machine_.state() != alg::TrackingState::kLost) {
    reference.T_world_previous = T_previous_;
    reference.color_offset_ratio = static_cast<double>(pre.stamp_ns - pre.depth_stamp_ns) * 1e-9 / interval_s;
  }
  alg::TrackingParams tp = state_machine_.gates(params_.tracking);
  tp.photometric_scale_m = photometricScale();
  tracking_counters_.photometric_scale_m = tp.photometric_scale_m;
  // From the last pose; when that is not good enough, from the constant
  // velocity prediction too, keeping the better.
  icp = alg::trackPointToPlane(pre, model_, T_last_, tp, reference, parallel_);
  if (params_.tracking.constant_velocity && (!icp.ok || !icp.degraded.empty()) &&
      state_machine_.state() != alg::TrackingState::kLost && !velocity_.isApprox(Eigen::Isometry3d::Identity())) {
    alg::IcpResult cv = alg::trackPointToPlane(pre, model_, T_last_ * velocity_, tp, reference, parallel_);
    ++tracking_counters_.velocity_retries;
    if (betterTrack(cv, icp)) {
      icp = std::move(cv);
      ++tracking_counters_.velocity_wins;
    }
  }
  if (icp.ok && state_machine_.state() == alg::TrackingState::kLost &&
      state_machine_.consecutiveLost() > static_cast<uint64_t>(std::max(0, params_.tracking.short_loss_frames))) {
    // DESIGN: lost, the last pose is stale; ICP from it that lands far away
    // may have slid along planes into a wrong pose that the depth still
    // agrees with (after a 1.5 s synthetic blackout: 0.24 m off, 90 % of
    // the residuals within the noise gate). After more than a short loss
    // such a result needs a second, independent estimate: relocalization's
    // PnP, which ICP then confirms.
    const Eigen::Isometry3d moved = T_last_.inverse() * icp.T_world_cam;
    const alg::RelocalizationParams& rp = params_.relocalization;
    if (alg::translationNorm(moved) > rp.max_icp_correction_m ||
        alg::rotationAngle(moved) * 180.0 / M_PI > rp.max_icp_correction_deg) {
      icp.ok = false;
      icp.failure = "moved " + std::to_string(std::lround(1000 * alg::translationNorm(moved))) +
                    " mm from the last pose while lost (needs relocalization to confirm)";
    }
  }
  attempts.model = &icp;
  alg::IcpResult odometry;
  if (!icp.ok && state_machine_.state() != alg::TrackingState::kLost && !previous_frame_.levels.empty()) {
    const std::vector<alg::ModelView> previous = alg::frameAsModel(previous_frame_, T_previous_);
    const Eigen::Isometry3d guess = params_.tracking.constant_velocity ? T_last_ * velocity_ : T_last_;
    odometry = alg::trackPointToPlane(pre, previous, guess, tp, reference, parallel_);
    attempts.odometry = &odometry;
  }
  alg::IcpResult relocalized;
  std::string relocalization_failure;
  const bool model_failed = !icp.ok || (state_machine_.state() == alg::TrackingState::kLost && !icp.degraded.empty());
  if (model_failed && !odometry.ok && params_.relocalization.enabled) {
    if (relocalize(pre, tp, relocalized, relocalization_failure)) attempts.relocalization = &relocalized;
  }
  if (icp.ok) state_machine_.observe(icp.consistent_ratio, params_.tracking.consistent_window);
  if (icp.ok && icp.degraded.empty() && icp.photometric_mean_abs > 0 && icp.mean_abs_residual_m > 0) {
    photometric_ratios_.push_back(icp.mean_abs_residual_m / icp.photometric_mean_abs);
    while (photometric_ratios_.size() > static_cast<size_t>(std::max(1, params_.tracking.photometric_scale_window))) {
      photometric_ratios_.pop_front();
    }
  }
  alg::TrackingDecision d = state_machine_.update(attempts);
  if (d.state == alg::TrackingState::kLost && !relocalization_failure.empty()) {
    d.reason += "; relocalization: " + relocalization_failure;
  }
  if (d.source == alg::PoseSource::kRelocalization) {
    T_world_cam = relocalized.T_world_cam;
    icp = relocalized;
  }
  if (d.source == alg::PoseSource::kModel) T_world_cam = icp.T_world_cam;
  if (d.source == alg::PoseSource::kOdometry) {
    T_world_cam = odometry.T_world_cam;
    icp = odometry;
  }
  return d;
}

alg::FrameFeatures Frontend::addToKeyframeDatabase(uint32_t id, const alg::PreprocessedFrame& frame,
                                                   const Eigen::Isometry3d& T_world_cam) {
  if (!frame.has_color || frame.intensity.empty()) return {};  // no texture to describe
  const auto t0 = std::chrono::steady_clock::now();
  cv::Mat gray;
  frame.intensity.convertTo(gray, CV_8U, 255.0);
  alg::FrameFeatures features = alg::extractFeatures(gray, frame.depth_m, camera_, params_.relocalization);
  keyframe_db_.add(id, features, T_world_cam);
  tracking_counters_.keyframe_features_ms +=
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return features;
}

void Frontend::addKeyframeFeatures(const KeyframeFeatures& f) {
  tracking_counters_.keyframe_features_ms += f.ms;
  const auto index = keyframe_index_.find(f.id);
  if (index == keyframe_index_.end() || index->second >= trajectory_.size()) return;  // a map since started anew
  keyframe_db_.add(f.id, f.features, trajectory_[index->second].T_world_cam);
}

bool Frontend::relocalize(const alg::PreprocessedFrame& pre, const alg::TrackingParams& tp, alg::IcpResult& verified,
                          std::string& why) {
  if (keyframe_db_.size() == 0) {
    why = "no keyframes in the database";
    return false;
  }
  if (!pre.has_color || pre.intensity.empty()) {
    why = "no color to match";
    return false;
  }
  const auto t0 = std::chrono::steady_clock::now();
  struct Timer {
    std::chrono::steady_clock::time_point t0;
    double& total;
    ~Timer() { total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(); }
  } timer{t0, tracking_counters_.relocalization_ms};
  ++tracking_counters_.relocalization_attempts;
  cv::Mat gray;
  pre.intensity.convertTo(gray, CV_8U, 255.0);
  const alg::FrameFeatures features = alg::extractFeatures(gray, pre.depth_m, camera_, params_.relocalization, false);
  const auto t_features = std::chrono::steady_clock::now();
  const std::vector<alg::RelocalizationCandidate> candidates =
      keyframe_db_.query(features, camera_, T_last_, tracking_counters_.relocalization_attempts - 1, &why);
  const auto t_query = std::chrono::steady_clock::now();
  tracking_counters_.relocalization_features_ms += std::chrono::duration<double, std::milli>(t_features - t0).count();
  tracking_counters_.relocalization_query_ms += std::chrono::duration<double, std::milli>(t_query - t_features).count();
  const alg::RelocalizationParams& rp = params_.relocalization;
  // The ICP check: against the model rendered at the candidate, without the
  // photometric term (the previous frame is not near this pose).
  for (size_t i = 0; i < candidates.size() && i < 3; ++i) {
    const alg::RelocalizationCandidate& c = candidates[i];
    renderModel(pre, c.T_world_cam);
    alg::IcpResult r = alg::trackPointToPlane(pre, model_, c.T_world_cam, tp, {}, parallel_);
    const Eigen::Isometry3d moved = c.T_world_cam.inverse() * r.T_world_cam;
    const bool agrees = alg::translationNorm(moved) <= rp.max_icp_correction_m &&
                        alg::rotationAngle(moved) * 180.0 / M_PI <= rp.max_icp_correction_deg;
    if (r.ok && r.degraded.empty() && agrees) {
      verified = std::move(r);
      return true;
    }
    ++tracking_counters_.relocalization_rejected;
    why = "keyframe " + std::to_string(c.keyframe_id) + " gave a pose (" + std::to_string(c.pnp_inliers) +
          " PnP inliers) that the model did not confirm (" +
          (r.ok ? (agrees ? r.degraded : std::string("ICP moved it too far")) : r.failure) + ")";
  }
  if (!candidates.empty()) renderModel(previous_frame_.levels.empty() ? pre : previous_frame_, T_last_);
  return false;
}

void Frontend::keepFeedbackKeyframe(uint32_t id, int64_t stamp_ns, const alg::IcpResult* icp,
                                    const Eigen::Isometry3d& T_previous_kf) {
  const alg::FeedbackParams& fp = params_.feedback;
  KeptKeyframe k;
  k.id = id;
  k.trajectory_index = trajectory_.size() - 1;  // this frame's entry
  k.T_fused = T_last_;
  // The buffers fusion read (a frame's buffers are never written after preprocessing).
  k.observation = {last_frame_.depth_m, last_frame_.rgb, last_frame_.levels[last_frame_.finest].confidence, camera_,
                   T_last_.cast<float>()};
  k.box_world = viewBox(last_frame_.levels.back().vertex, T_last_.cast<float>(), map_.truncation() + map_.blockSize());
  kept_.push_back(std::move(k));
  // The window's keyframes and one more (a correction in flight for the one
  // that just slid out still lands).
  while (static_cast<int>(kept_.size()) > std::max(1, fp.window) + 1) kept_.pop_front();

  const int level = std::clamp(fp.image_level, 0, static_cast<int>(last_frame_.levels.size()) - 1);
  const alg::FrameLevel& l = last_frame_.levels[static_cast<size_t>(level)];
  alg::WindowKeyframe w;
  w.id = id;
  w.stamp_ns = stamp_ns;
  w.T_world_cam = T_last_;
  w.camera = l.camera;
  w.depth = l.depth;
  // Without color the intensity is flat: no gradient, so no photometric
  // residual (depth only).
  w.intensity =
      last_frame_.has_color && !l.intensity.empty() ? l.intensity : cv::Mat(l.depth.size(), CV_32F, cv::Scalar(0));
  if (icp && icp->ok) {
    w.odometry_from_previous = T_previous_kf.inverse() * T_last_;
    // ICP perturbs on the left in the world frame (T <- exp(xi_w) T); the
    // window on the right (T <- T exp(xi)): xi_w = Ad(T) xi.
    const alg::Matrix6d Ad = alg::adjoint(T_last_);
    w.odometry_information = Ad.transpose() * icp->information * Ad;
  }
  feedback_out_.push_back(std::move(w));
}

std::shared_ptr<const alg::TsdfMap> Frontend::feedbackSnapshot() {
  const auto t0 = std::chrono::steady_clock::now();
  Eigen::AlignedBox3f box;  // empty
  for (const KeptKeyframe& k : kept_) box.extend(k.box_world);
  // DESIGN: into the memory of a copy given back when there is one: a
  // fresh copy (25 MB on fr1/xyz) was mostly page faults, 2.7-4.1 ms.
  constexpr size_t kSlots = 3;
  auto slot = std::find_if(snapshot_slots_.begin(), snapshot_slots_.end(), [](const SnapshotSlot& s) { return !s.in_use; });
  if (slot == snapshot_slots_.end() && snapshot_slots_.size() < kSlots) {
    snapshot_slots_.push_back({std::make_shared<alg::TsdfMap>(map_.params()), false});
    slot = std::prev(snapshot_slots_.end());
  }
  std::shared_ptr<alg::TsdfMap> snapshot =
      slot != snapshot_slots_.end() ? slot->map : std::make_shared<alg::TsdfMap>(map_.params());
  if (slot != snapshot_slots_.end()) slot->in_use = true;
  snapshot->assignBlocks(map_, box);  // an empty box copies nothing
  ++feedback_counters_.snapshots;
  feedback_counters_.snapshot_blocks += snapshot->blockCount();
  feedback_counters_.snapshot_ms +=
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return snapshot;
}

void Frontend::reuseFeedbackSnapshot(const alg::TsdfMap* done) {
  for (SnapshotSlot& s : snapshot_slots_) {
    if (s.map.get() == done) s.in_use = false;
  }
}

std::vector<alg::WindowKeyframe> Frontend::takeFeedbackKeyframes() {
  std::vector<alg::WindowKeyframe> out;
  out.swap(feedback_out_);
  return out;
}

bool Frontend::applyKeyframeCorrection(const KeyframeCorrection& c) {
  auto it = std::find_if(kept_.begin(), kept_.end(), [&](const KeptKeyframe& k) { return k.id == c.keyframe_id; });
  if (it == kept_.end() || it->trajectory_index >= trajectory_.size() || !c.T_world_cam.matrix().allFinite()) {
    ++feedback_counters_.corrections_late;
    return false;
  }
  const size_t index = it->trajectory_index;
  // DESIGN: only the keyframe's own entry moves. Frames are tracked against
  // the map, not chained to their keyframe, so the frames after it do not
  // carry its error: moving them by its correction added the window's noise
  // to every frame (synthetic orbit: ATE +44% vs +1.9% keyframe-only), and
  // with injected drift the keyframe-only correction does as well (-52% vs
  // -50%): re-integration carries the fix forward.
  trajectory_[index].T_world_cam = c.T_world_cam;
  ++feedback_counters_.corrections;
  // DESIGN: nor does the live pose jump with the newest keyframe's
  // correction: the frames that follow are tracked against the map, which
  // carries the correction once the keyframe is re-integrated. Moving the
  // live pose, the previous frame and the photometric reference with it
  // made every correction's error permanent: on the whole TUM fr1/xyz
  // (refinement and loop closure off) ATE 3.52 cm with feedback against
  // 1.20 cm without, rotation errors growing in steps of 1-3 degrees at
  // keyframes; 6.22 cm with the dense check below as well, 4.22 cm with the
  // model raycast again after the jump. Without the jump 1.19 cm. On the
  // synthetic drift test the jump removed more of an injected drift (over
  // a fifth of it; a tenth without).
  keyframe_db_.updatePose(c.keyframe_id, c.T_world_cam);
  for (auto& k : keyframe_images_) {
    if (k.id == c.keyframe_id) k.T_world_cam = c.T_world_cam.cast<float>();
  }
  const Eigen::Isometry3d moved = it->T_fused.inverse() * c.T_world_cam;
  const double angle_deg = Eigen::AngleAxisd(moved.linear()).angle() * 180.0 / M_PI;
  if (moved.translation().norm() > params_.feedback.reintegrate_translation_m ||
      angle_deg > params_.feedback.reintegrate_rotation_deg) {
    if (std::find(reintegrate_queue_.begin(), reintegrate_queue_.end(), c.keyframe_id) == reintegrate_queue_.end()) {
      reintegrate_queue_.push_back(c.keyframe_id);
    }
  }
  return true;
}

int Frontend::reintegratePending(int max) {
  int done = 0;
  while (done < max && !reintegrate_queue_.empty()) {
    const uint32_t id = reintegrate_queue_.front();
    reintegrate_queue_.pop_front();
    auto it = std::find_if(kept_.begin(), kept_.end(), [&](const KeptKeyframe& k) { return k.id == id; });
    if (it == kept_.end() || it->trajectory_index >= trajectory_.size()) continue;
    const auto t0 = std::chrono::steady_clock::now();
    const Eigen::Isometry3d T_new = trajectory_[it->trajectory_index].T_world_cam;
    alg::DepthObservation obs = it->observation;
    obs.T_world_cam = it->T_fused.cast<float>();
    alg::deintegrate(map_, obs, parallel_);
    obs.T_world_cam = T_new.cast<float>();
    alg::integrate(map_, obs, parallel_);
    it->T_fused = T_new;
    ++feedback_counters_.reintegrations;
    feedback_counters_.reintegrate_ms +=
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    ++done;
  }
  return done;
}

void Frontend::scoreKeyframe(FrameResult& r) {
  // The model view was raycast at this pose after the keyframe was fused,
  // at the model level; the frame's level of the same size pairs with it.
  const alg::ModelView& model = model_.front();
  const alg::FrameLevel* level = nullptr;
  for (const auto& l : last_frame_.levels) {
    if (l.depth.size() == model.depth.size()) {
      level = &l;
      break;
    }
  }
  if (!level) return;
  alg::FrameLevel frame = *level;                           // headers only
  if (!last_frame_.has_color) frame.intensity = cv::Mat();  // no photometric mismatch without color
  quality_.update(map_, {r.keyframe_id, T_last_.cast<float>(), &frame, &model});
  scores_ = quality_.score(map_.truncation());
  rois_ = quality_.selectRois(scores_, map_.voxelSize());
  r.rois = rois_.size();
}

void Frontend::keepKeyframeImages(uint32_t id) {
  // At half resolution (what refinement samples: 5.7 mm pixels at 3 m,
  // below a 1 cm voxel), copied: the frame's buffers are not ours to keep.
  const int level = std::min<int>(1, static_cast<int>(last_frame_.levels.size()) - 1);
  if (level < 0) return;
  const alg::FrameLevel& l = last_frame_.levels[level];
  alg::KeyframeImages k;
  k.id = id;
  k.camera = l.camera;
  k.T_world_cam = T_last_.cast<float>();
  // DESIGN: refinement trains on the measurements fusion averaged, not on
  // the denoised pyramid (see averageDepth2x2).
  k.depth = level == 1 ? alg::averageDepth2x2(last_frame_.depth_m) : l.depth.clone();
  // Nor on depth fusion never takes: beyond max_integration_depth_m (or
  // outside the preprocessing range) the field would fit surfaces the map
  // deliberately leaves out, and with completion write them back (on the
  // Replica slice, 10-13 % of the pixels lie beyond 4 m, and there the ROIs
  // rendered no surface for 83 % of their pixels).
  const float lo = static_cast<float>(params_.preprocess.min_depth_m);
  const float hi = static_cast<float>(std::min(params_.preprocess.max_depth_m, params_.tsdf.max_integration_depth_m));
  // A plain loop, not cv::Mat::forEach: that runs on OpenCV's TBB pool,
  // whose synchronization ThreadSanitizer does not see.
  for (int v = 0; v < k.depth.rows; ++v) {
    float* row = k.depth.ptr<float>(v);
    for (int u = 0; u < k.depth.cols; ++u) {
      if (!(row[u] >= lo && row[u] <= hi)) row[u] = 0.0f;
    }
  }
  if (!l.normal.empty()) k.normal = l.normal.clone();
  if (last_frame_.has_color && !last_frame_.rgb.empty()) {
    cv::resize(last_frame_.rgb, k.rgb, l.depth.size(), 0, 0, cv::INTER_AREA);
  }
  keyframe_images_.push_back(std::move(k));
  // DESIGN: over the cap, out goes the keyframe fewest blocks keep (the
  // oldest of those), never the newest: with the quality map's blocks
  // keeping views spread in direction, the images an ROI trains on reach
  // back past the last few keyframes.
  while (static_cast<int>(keyframe_images_.size()) > std::max(1, params_.refine.keyframe_images)) {
    auto out = keyframe_images_.begin();
    uint32_t fewest = quality_.keyframeReferences(out->id);
    for (auto it = std::next(out); it != std::prev(keyframe_images_.end()) && fewest > 0; ++it) {
      const uint32_t refs = quality_.keyframeReferences(it->id);
      if (refs < fewest) {
        fewest = refs;
        out = it;
      }
    }
    keyframe_images_.erase(out);
  }
}

void Frontend::makeRefineJobs(uint32_t keyframe_id) {
  int made = 0;
  const auto cooldown = static_cast<uint32_t>(std::max(0, params_.refine.cooldown_keyframes));
  const int limit = refine_budget_ < 0 ? params_.refine.max_jobs_per_keyframe
                                       : std::min(params_.refine.max_jobs_per_keyframe, refine_budget_);
  for (const alg::Roi& roi : rois_) {
    if (made >= limit) break;
    size_t busy = 0;
    for (const auto& key : roi.blocks) {
      const auto it = block_submitted_.find(alg::packBlockKey(key));
      busy += it != block_submitted_.end() && keyframe_id - it->second < cooldown;
    }
    if (2 * busy > roi.blocks.size()) continue;
    RefineJob job;
    for (uint32_t id : roi.keyframes) {
      for (const auto& k : keyframe_images_) {
        if (k.id == id) job.keyframes.push_back(k);  // headers: the images are shared, never written
      }
    }
    if (job.keyframes.empty() || static_cast<int>(job.keyframes.size()) < params_.refine.min_job_keyframes) continue;
    job.id = next_job_id_++;
    job.keyframe_id = keyframe_id;
    job.map_epoch = map_epoch_;
    job.roi = roi;
    job.snapshot = std::make_shared<const alg::TsdfMap>(alg::copyBlocks(map_, roi.box_world));
    // DESIGN: sampling the field for feedback's implicit channels costs a
    // job 6-38 ms on the soak's room (the write-back itself 2.5-6.4 ms):
    // with feedback off, a 30 FPS frame's slack never fitted that slice,
    // and every job behind it was cancelled.
    job.implicit_surface = params_.feedback.enabled &&
                           (params_.feedback.lambda_photo_implicit > 0 || params_.feedback.lambda_depth_implicit > 0);
    for (const auto& key : roi.blocks) block_submitted_[alg::packBlockKey(key)] = keyframe_id;
    pending_jobs_.push_back(std::move(job));
    ++jobs_made_;
    ++made;
  }
  while (static_cast<int>(pending_jobs_.size()) > std::max(1, params_.refine.max_pending_jobs)) {
    pending_jobs_.erase(pending_jobs_.begin());
    ++jobs_dropped_;
  }
}

std::vector<RefineJob> Frontend::takeRefineJobs() {
  std::vector<RefineJob> out;
  out.swap(pending_jobs_);
  return out;
}

alg::PatchStats Frontend::applyRefinement(const RefineOutcome& outcome) {
  if (outcome.map_epoch != map_epoch_) {  // cut from a map a loop closure has since rebuilt
    ++loop_counters_.stale_refinements;
    return {};
  }
  for (const auto& [key, sigma] : outcome.result.neural_sigma) quality_.setNeuralSigma(key, sigma);
  if (outcome.surface && outcome.surface->sampledNodes() > 0) {
    const std::lock_guard lock(surfaces_mutex_);
    const Eigen::AlignedBox3f& box = outcome.surface->box();
    surfaces_.erase(std::remove_if(surfaces_.begin(), surfaces_.end(),
                                   [&](const auto& s) { return box.contains(s->box().center()); }),
                    surfaces_.end());
    surfaces_.push_front(outcome.surface);
    if (surfaces_.size() > kMaxImplicitSurfaces) surfaces_.pop_back();
  }
  if (const auto& detail = outcome.result.detail; detail && !detail->empty()) {
    const std::lock_guard lock(surfaces_mutex_);
    for (auto it = details_.begin(); it != details_.end();) {
      if (detail->box.contains((*it)->box)) {
        detail_bytes_ -= (*it)->memoryBytes();
        it = details_.erase(it);
      } else {
        ++it;
      }
    }
    details_.push_back(detail);
    detail_bytes_ += detail->memoryBytes();
    while (detail_bytes_ > kMaxDetailBytes && details_.size() > 1) {
      detail_bytes_ -= details_.front()->memoryBytes();
      details_.pop_front();
    }
  }
  return alg::applyPatch(map_, outcome.result.patch);
}

std::vector<std::shared_ptr<const alg::ImplicitSurface>> Frontend::implicitSurfaces() const {
  const std::lock_guard lock(surfaces_mutex_);
  return {surfaces_.begin(), surfaces_.end()};
}

std::vector<std::shared_ptr<const alg::RefinedDetail>> Frontend::details() const {
  const std::lock_guard lock(surfaces_mutex_);
  return {details_.begin(), details_.end()};
}

alg::TriangleMesh Frontend::mesh(const alg::MeshParams& params) const {
  return alg::extractHybridMesh(map_, params, details());
}

alg::PatchStats Frontend::applyPatch(const alg::TsdfPatch& patch) {
  return alg::applyPatch(map_, patch);
}

void Frontend::renderModel(const alg::PreprocessedFrame& fused, const Eigen::Isometry3d& T_world_cam) {
  const int levels = static_cast<int>(fused.levels.size());
  // The model is raycast at pyramid level `model_level` (the fused frame's
  // depth at that level as the hint); finer tracking levels associate into
  // that same view, coarser ones into subsampled copies.
  const int model_level =
      std::clamp(alg::modelLevel(params_.tracking, camera_.width), 0, static_cast<int>(fused.levels.size()) - 1);
  cv::Mat hint = model_level == 0 ? fused.depth_m : fused.levels[model_level].depth;
  // Where the frame has no depth, the previous model view (one frame of
  // motion away) predicts the surface: those rays then bracket it directly
  // instead of marching from the tile bound (a quarter of the rays on the
  // TUM slice). DESIGN: where neither has a surface, marching found nothing
  // most of the time and cost half the raycast, so only every fourth such
  // pixel (a different one each frame) is cast; a hit there becomes the
  // prediction for its pixel in the next frame, so holes the map can fill
  // are filled within a few frames.
  if (static_cast<int>(model_.size()) > model_level && model_[model_level].depth.size() == hint.size()) {
    hint = hint.clone();
    const cv::Mat& previous = model_[model_level].depth;
    const int phase = static_cast<int>(trajectory_.size() % 16);
    for (int v = 0; v < hint.rows; ++v) {
      float* h = hint.ptr<float>(v);
      const float* p = previous.ptr<float>(v);
      const int row_phase = (phase + 4 * (v & 3)) & 15;
      for (int u = 0; u < hint.cols; ++u) {
        if (h[u] > 0.0f) continue;
        h[u] = p[u] > 0.0f ? p[u] : (((u + row_phase) & 15) == 0 ? 0.0f : -1.0f);
      }
    }
  }
  model_.clear();
  model_.push_back(
      alg::raycast(map_, camera_.level(model_level), T_world_cam.cast<float>(), params_.raycast, false, parallel_, hint));
  for (int l = 1; l <= model_level && l < levels; ++l) model_.push_back(model_.back());
  while (static_cast<int>(model_.size()) < levels) model_.push_back(alg::subsampleView(model_.back()));
}

}  // namespace hxmap::rt
