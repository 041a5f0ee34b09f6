// Loop closure, the frontend's part: each keyframe with its odometry goes
// to the loop closer (loop_closer.cpp); an accepted closure comes back as
// a correction that moves every frame with its keyframe and brings the
// map fused anew from the keyframes at their new poses.
#include <algorithm>
#include <mutex>
#include <optional>
#include <utility>

#include <spdlog/spdlog.h>

#include "hxmap/frontend/frontend.hpp"
#include "hxmap/geometry/se3.hpp"

namespace hxmap::rt {

void Frontend::sendToLoopCloser(uint32_t id, alg::FrameFeatures features, const alg::PreprocessedFrame& previous_kf,
                                const Eigen::Isometry3d& T_previous_kf, const Eigen::Isometry3d& T_previous_kf_color,
                                const Eigen::Isometry3d& T_world_kf) {
  LoopKeyframe kf;
  kf.id = id;
  kf.epoch = loop_epoch_;
  kf.T_world_kf = T_world_kf;
  if (id > keyframe_id_base_) {  // not this run's first keyframe
    kf.previous = previous_kf;  // headers
    kf.T_world_previous = T_previous_kf;
    kf.T_world_previous_color = T_previous_kf_color;
    kf.T_depth_color = colorOffset(last_frame_);
    kf.photometric_scale_m = photometricScale();
  }
  kf.features = std::move(features);
  kf.describe = describe_elsewhere_;
  kf.close = params_.loop_closure.enabled;
  kf.frame = last_frame_;  // headers: the buffers are shared, never written again
  kf.observation = {last_frame_.depth_m, last_frame_.rgb, last_frame_.levels[last_frame_.finest].confidence, camera_,
                    T_world_kf.cast<float>()};
  if (!loop_closer_) {
    loop_out_.push_back(std::move(kf));
    return;
  }
  loop_closer_->add(std::move(kf));
  while (loop_closer_->step()) {
  }
  if (std::optional<LoopCorrection> c = loop_closer_->takeCorrection()) applyLoopCorrection(*c);
}

void Frontend::applyLoopCorrection(LoopCorrection& c) {
  if (c.epoch != loop_epoch_ + 1 || !c.map) {
    spdlog::warn("loop correction {} out of order (frontend at {}): ignored", c.epoch, loop_epoch_);
    return;
  }
  ++loop_epoch_;
  ++loop_counters_.applied;
  // Each keyframe's correction; the frames between two keyframes get theirs
  // interpolated by time, frames after the newest keyframe of the graph
  // move with it.
  // DESIGN: with each keyframe's correction applied to every frame up to
  // the next keyframe, the written trajectory jumped at each keyframe by
  // the difference of two neighbouring corrections (up to 2.4 deg on the
  // whole fr1/xyz); the frames between were tracked from the first of the
  // two, so the change the graph made to the motion between them is spread
  // over those frames.
  std::vector<std::pair<size_t, Eigen::Isometry3d>> corrections;  // trajectory index, correction
  for (const auto& [id, T_new] : c.nodes) {
    const auto index = keyframe_index_.find(id);
    if (index == keyframe_index_.end() || index->second >= trajectory_.size()) continue;
    corrections.emplace_back(index->second, T_new * trajectory_[index->second].T_world_cam.inverse());
    keyframe_db_.updatePose(id, T_new);
  }
  if (corrections.empty()) return;
  std::sort(corrections.begin(), corrections.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  corrections.back().second = c.newest;
  auto correctionAt = [&](size_t index) -> std::optional<Eigen::Isometry3d> {
    const auto it = std::upper_bound(corrections.begin(), corrections.end(), index,
                                     [](size_t i, const auto& k) { return i < k.first; });
    if (it == corrections.begin()) return std::nullopt;
    const auto& [ia, Ca] = *std::prev(it);
    if (it == corrections.end() || index == ia) return Ca;
    const auto& [ib, Cb] = *it;
    const double span = static_cast<double>(trajectory_[ib].stamp_ns - trajectory_[ia].stamp_ns);
    const double s =
        span > 0
            ? std::clamp(static_cast<double>(trajectory_[index].stamp_ns - trajectory_[ia].stamp_ns) / span, 0.0, 1.0)
            : 0.0;
    return alg::interpolate(Ca, Cb, s);
  };
  for (size_t i = corrections.front().first; i < trajectory_.size(); ++i) {
    trajectory_[i].T_world_cam = *correctionAt(i) * trajectory_[i].T_world_cam;
  }
  for (auto& k : keyframe_images_) {
    const auto index = keyframe_index_.find(k.id);
    const std::optional<Eigen::Isometry3d> d =
        index == keyframe_index_.end() ? std::nullopt : correctionAt(index->second);
    if (d) k.T_world_cam = (*d * k.T_world_cam.cast<double>()).cast<float>();
  }
  // The live state moves with the newest keyframe.
  const Eigen::Isometry3d& newest = c.newest;
  T_last_ = newest * T_last_;
  T_previous_ = newest * T_previous_;
  T_previous_color_ = newest * T_previous_color_;
  T_keyframe_color_ = newest * T_keyframe_color_;
  T_last_kf_ = newest * T_last_kf_;
  T_world_odom_ = newest * T_world_odom_;
  // Pose feedback's kept keyframes were fused at poses that no longer
  // exist in the rebuilt map: they leave the re-integration queue.
  kept_.clear();
  reintegrate_queue_.clear();
  {
    // Revisions go on from the old map's, every block changed: map
    // publishers that follow revisions send the whole new map.
    c.map->markAllChanged(map_.revision());
    map_ = std::move(*c.map);
    // The rebuilt map holds what the keyframes saw; blocks held out of
    // memory describe the old one.
    if (backing_) backing_->clear();
    map_.setBacking(backing_);
  }
  c.map.reset();
  ++map_epoch_;
  pending_jobs_.clear();  // cut from the old map
  block_submitted_.clear();
  quality_ = alg::QualityMap(params_.quality);  // its statistics describe the old map's blocks
  scores_.clear();
  rois_.clear();
  {
    const std::lock_guard lock(surfaces_mutex_);
    surfaces_.clear();  // refined fields and detail sit where the old map had the surface
    details_.clear();
    detail_bytes_ = 0;
  }
  if (initialized_) renderModel(last_frame_, T_last_);
}

LoopClosureCounters Frontend::loopClosureCounters() const {
  LoopClosureCounters c = loop_closer_ ? loop_closer_->counters() : LoopClosureCounters{};
  c.applied = loop_counters_.applied;
  c.stale_refinements = loop_counters_.stale_refinements;
  return c;
}

}  // namespace hxmap::rt
