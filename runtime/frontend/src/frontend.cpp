#include "hxmap/frontend/frontend.hpp"

#include <algorithm>
#include <chrono>

#include <opencv2/imgproc.hpp>

#include "hxmap/tsdf/integrate.hpp"

namespace hxmap::rt {

namespace {
class StageTimer {
 public:
  explicit StageTimer(double& out_ms) : out_(out_ms), start_(std::chrono::steady_clock::now()) {}
  ~StageTimer() {
    out_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count();
  }
  StageTimer(const StageTimer&) = delete;
  StageTimer& operator=(const StageTimer&) = delete;

 private:
  double& out_;
  std::chrono::steady_clock::time_point start_;
};
}  // namespace

Frontend::Frontend(const alg::PinholeCamera& camera, const FrontendParams& params, ParallelFor parallel)
    : camera_(camera), params_(params), parallel_(std::move(parallel)), map_(params.tsdf), quality_(params.quality) {}

FrameResult Frontend::process(const RgbdFrame& frame) {
  FrameResult r;
  r.stamp_ns = frame.stamp_ns;

  // 1. Preprocess: depth in meters, denoise, pyramid, normals, confidence.
  alg::PreprocessedFrame pre;
  {
    StageTimer t(r.stage_ms[kPreprocess]);
    pre = alg::preprocessFrame(frame, camera_, params_.preprocess, parallel_);
  }
  const int min_valid = std::max(params_.tracking.min_inliers, camera_.width * camera_.height / 100);

  // 2. Track against the model rendered at the last pose (constant velocity guess).
  Eigen::Isometry3d T = T_initial_;
  if (pre.valid_pixels < min_valid) {
    r.failure = "too little valid depth (" + std::to_string(pre.valid_pixels) + " pixels)";
  } else if (!initialized_) {
    r.tracked = true;
  } else {
    StageTimer t(r.stage_ms[kTrack]);
    const alg::IcpResult icp = alg::trackPointToPlane(
        pre, model_, params_.tracking.constant_velocity ? T_last_ * velocity_ : T_last_, params_.tracking,
        alg::PhotometricReference{&last_frame_, T_last_}, parallel_);
    r.tracked = icp.ok;
    r.failure = icp.failure;
    r.inliers = icp.inliers;
    r.rms_residual_m = icp.rms_residual_m;
    T = icp.T_world_cam;
  }

  if (!r.tracked) {
    // Keep the map and the last good pose; restart motion from rest.
    ++lost_frames_;
    velocity_.setIdentity();
    r.T_world_cam = initialized_ ? T_last_ : T_initial_;
    trajectory_.push_back({frame.stamp_ns, r.T_world_cam});
    return r;
  }

  // 3. Integrate the range-gated depth with per-pixel confidence.
  {
    StageTimer t(r.stage_ms[kIntegrate]);
    alg::DepthObservation obs{pre.depth_m, pre.rgb, pre.levels[pre.finest].confidence, camera_, T.cast<float>()};
    alg::integrate(map_, obs, parallel_);
  }
  velocity_ = initialized_ ? T_last_.inverse() * T : Eigen::Isometry3d::Identity();
  T_last_ = T;
  last_frame_ = std::move(pre);
  r.integrated = true;
  r.T_world_cam = T;

  // 4. Raycast the model at the new pose for the next frame (the fused depth
  //    predicts where each ray meets the surface).
  {
    StageTimer t(r.stage_ms[kRaycast]);
    renderModel(last_frame_);
  }

  // 5. Keyframes by motion and time.
  if (!initialized_ || alg::isNewKeyframe(T_last_kf_, T, last_kf_ns_, frame.stamp_ns, params_.tracking)) {
    r.keyframe = true;
    r.keyframe_id = static_cast<uint32_t>(keyframes_);
    T_last_kf_ = T;
    last_kf_ns_ = frame.stamp_ns;
    ++keyframes_;
    if (params_.quality_enabled) {
      StageTimer t(r.stage_ms[kQuality]);
      scoreKeyframe(r);
      if (params_.refine_enabled) {
        keepKeyframeImages(r.keyframe_id);
        makeRefineJobs(r.keyframe_id);
      }
    }
  }
  initialized_ = true;
  trajectory_.push_back({frame.stamp_ns, T});
  return r;
}

bool Frontend::applyPoseCorrection(const PoseCorrection& c) {
  for (auto it = trajectory_.rbegin(); it != trajectory_.rend(); ++it) {
    if (it->stamp_ns != c.stamp_ns) continue;
    it->T_world_cam = c.T_world_cam;
    if (c.stamp_ns == last_kf_ns_) T_last_kf_ = c.T_world_cam;
    return true;
  }
  return false;
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
  alg::FrameLevel frame = *level;                  // headers only
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
  if (!l.normal.empty()) k.normal = l.normal.clone();
  if (last_frame_.has_color && !last_frame_.rgb.empty()) {
    cv::resize(last_frame_.rgb, k.rgb, l.depth.size(), 0, 0, cv::INTER_AREA);
  }
  keyframe_images_.push_back(std::move(k));
  while (static_cast<int>(keyframe_images_.size()) > std::max(1, params_.keyframe_images)) keyframe_images_.pop_front();
}

void Frontend::makeRefineJobs(uint32_t keyframe_id) {
  int made = 0;
  const auto cooldown = static_cast<uint32_t>(std::max(0, params_.refine_cooldown_keyframes));
  for (const alg::Roi& roi : rois_) {
    if (made >= params_.max_jobs_per_keyframe) break;
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
    if (job.keyframes.empty() || static_cast<int>(job.keyframes.size()) < params_.min_job_keyframes) continue;
    job.id = next_job_id_++;
    job.keyframe_id = keyframe_id;
    job.roi = roi;
    job.snapshot = std::make_shared<const alg::TsdfMap>(alg::copyBlocks(map_, roi.box_world));
    for (const auto& key : roi.blocks) block_submitted_[alg::packBlockKey(key)] = keyframe_id;
    pending_jobs_.push_back(std::move(job));
    ++jobs_made_;
    ++made;
  }
  while (static_cast<int>(pending_jobs_.size()) > std::max(1, params_.max_pending_jobs)) {
    pending_jobs_.erase(pending_jobs_.begin());
    ++jobs_dropped_;
  }
}

std::vector<RefineJob> Frontend::takeRefineJobs() {
  std::vector<RefineJob> out;
  out.swap(pending_jobs_);
  return out;
}

RefineOutcome runRefineJob(const RefineJob& job, const alg::ImplicitParams& params) {
  using Clock = std::chrono::steady_clock;
  auto ms = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  RefineOutcome out;
  out.job_id = job.id;
  const auto t0 = Clock::now();
  alg::RoiRefiner refiner(*job.snapshot, job.roi.box_world, job.keyframes, params);
  const auto t1 = Clock::now();
  while (refiner.iterate(std::max(1, params.slice_iterations))) {
    if (ms(t1, Clock::now()) >= params.time_budget_ms) {
      out.out_of_time = true;
      break;
    }
  }
  const auto t2 = Clock::now();
  out.result = refiner.result();
  const auto t3 = Clock::now();
  out.setup_ms = ms(t0, t1), out.train_ms = ms(t1, t2), out.result_ms = ms(t2, t3);
  return out;
}

alg::PatchStats Frontend::applyRefinement(const RefineOutcome& outcome) {
  for (const auto& [key, sigma] : outcome.result.neural_sigma) quality_.setNeuralSigma(key, sigma);
  return alg::applyPatch(map_, outcome.result.patch);
}

void Frontend::renderModel(const alg::PreprocessedFrame& fused) {
  const int levels = static_cast<int>(fused.levels.size());
  // The model is raycast at pyramid level `model_level` (the fused frame's
  // depth at that level as the hint); finer tracking levels associate into
  // that same view, coarser ones into subsampled copies.
  const int model_level = std::clamp(params_.tracking.model_level, 0, static_cast<int>(fused.levels.size()) - 1);
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
    const int phase = static_cast<int>(trajectory_.size() % 4);
    for (int v = 0; v < hint.rows; ++v) {
      float* h = hint.ptr<float>(v);
      const float* p = previous.ptr<float>(v);
      for (int u = 0; u < hint.cols; ++u) {
        if (h[u] > 0.0f) continue;
        h[u] = p[u] > 0.0f ? p[u] : (((u + 2 * v + phase) & 3) == 0 ? 0.0f : -1.0f);
      }
    }
  }
  model_.clear();
  model_.push_back(
      alg::raycast(map_, camera_.level(model_level), T_last_.cast<float>(), params_.raycast, false, parallel_, hint));
  for (int l = 1; l <= model_level && l < levels; ++l) model_.push_back(model_.back());
  while (static_cast<int>(model_.size()) < levels) model_.push_back(alg::subsampleView(model_.back()));
}

}  // namespace hxmap::rt
