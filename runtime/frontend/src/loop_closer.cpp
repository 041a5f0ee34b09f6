#include "hxmap/frontend/loop_closer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#include <spdlog/spdlog.h>

#include "hxmap/feedback/residuals.hpp"
#include "memory_budget.hpp"

namespace hxmap::rt {

namespace {
double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}
double degrees(double rad) { return rad * 180.0 / M_PI; }

/// The largest move of any node between two sets of poses.
std::pair<double, double> largestMove(const std::map<uint32_t, Eigen::Isometry3d>& before,
                                      const std::map<uint32_t, Eigen::Isometry3d>& after) {
  double m = 0, deg = 0;
  for (const auto& [node, T_before] : before) {
    const Eigen::Isometry3d d = T_before.inverse() * after.at(node);
    m = std::max(m, alg::translationNorm(d));
    deg = std::max(deg, degrees(alg::rotationAngle(d)));
  }
  return {m, deg};
}
// Deep copies of images, a shared buffer copied once (the copies share it
// as the originals did).
class ImageCopier {
 public:
  void copy(cv::Mat& m) {
    if (m.empty()) return;
    const Key key{m.data, m.rows, m.cols, m.type()};
    auto it = copies_.find(key);
    if (it == copies_.end()) it = copies_.emplace(key, m.clone()).first;
    m = it->second;
  }
  void copy(alg::PreprocessedFrame& f) {
    for (cv::Mat* m : {&f.depth_m, &f.rgb, &f.intensity}) copy(*m);
    for (alg::FrameLevel& l : f.levels) {
      for (cv::Mat* m : {&l.depth, &l.vertex, &l.normal, &l.confidence, &l.intensity, &l.intensity_grad}) copy(*m);
    }
  }

 private:
  using Key = std::tuple<const uchar*, int, int, int>;
  std::map<Key, cv::Mat> copies_;
};
}  // namespace

LoopKeyframe withOwnImages(LoopKeyframe kf) {
  ImageCopier copier;
  if (kf.previous) copier.copy(*kf.previous);
  copier.copy(kf.frame);
  copier.copy(kf.observation.depth_m);
  copier.copy(kf.observation.rgb);
  copier.copy(kf.observation.confidence);
  return kf;
}

KeyframeFeatures describeKeyframe(LoopKeyframe& kf, const alg::RelocalizationParams& params) {
  const auto t0 = std::chrono::steady_clock::now();
  KeyframeFeatures out;
  out.id = kf.id;
  kf.describe = false;
  if (kf.frame.has_color && !kf.frame.intensity.empty()) {
    cv::Mat gray;
    kf.frame.intensity.convertTo(gray, CV_8U, 255.0);
    kf.features = alg::extractFeatures(gray, kf.frame.depth_m, kf.observation.camera, params);
    // The frontend's copy shares nothing with the loop closer's.
    out.features = kf.features;
    out.features.descriptors = kf.features.descriptors.clone();
  }
  out.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

LoopCloser::LoopCloser(const LoopCloserParams& params, const alg::PinholeCamera& camera, ParallelFor parallel)
    : params_(params),
      camera_(camera),
      parallel_(std::move(parallel)),
      database_(params.relocalization),
      map_(params.tsdf) {}

bool LoopCloser::step() {
  const auto t0 = std::chrono::steady_clock::now();
  switch (phase_) {
    case Phase::kIdle:
      if (pending_.empty()) return false;
      begin();
      break;
    case Phase::kQuery:
      if (!query_->step()) {
        candidates_ = query_->candidates();
        counters_.candidates += candidates_.size();
        query_.reset();
        next_candidate_ = 0;
        phase_ = Phase::kVerify;
      }
      counters_.detect_ms += msSince(t0);
      break;
    case Phase::kVerify:
      verifyNext();
      counters_.detect_ms += msSince(t0);
      break;
    case Phase::kSolve:
      solve();
      counters_.solve_ms += msSince(t0);
      break;
    case Phase::kRebuild:
      rebuildStep();
      counters_.rebuild_ms += msSince(t0);
      break;
  }
  return true;
}

bool LoopCloser::shed() {
  if (phase_ == Phase::kIdle && pending_.size() > params_.max_pending) {
    // The oldest queued keyframes into the graph at once (microseconds
    // each); the rest wait on.
    const size_t n = pending_.size() - params_.max_pending;
    counters_.shed += n;
    for (size_t k = 0; k < n; ++k) begin(true);
    return true;
  }
  if (phase_ != Phase::kQuery && phase_ != Phase::kVerify) return false;
  ++counters_.shed;
  query_.reset();
  finishKeyframe();
  return true;
}

void LoopCloser::seed(const alg::TsdfMap& map, const alg::KeyframeDatabase& keyframes) {
  base_ = std::make_shared<const alg::TsdfMap>(map);
  map_ = map;
  database_ = keyframes;
  for (const alg::KeyframeDatabase::Keyframe& k : keyframes.keyframes()) {
    graph_.setNode(k.id, k.T_world_cam);
    graph_.fixNode(k.id);
  }
  fix_next_ = true;
}

Eigen::Isometry3d LoopCloser::uncheckedOdometry(const LoopKeyframe& kf) {
  ++counters_.odometry_unchecked;
  return kf.T_world_previous.inverse() * kf.T_world_kf;
}

void LoopCloser::begin(bool shed) {
  current_ = std::move(pending_.front());
  pending_.pop_front();
  // Behind (a newer keyframe waits): this one is not compared. Shed (the
  // queue outgrew max_pending): it only takes its place in the graph, with
  // tracking's motion unchecked, and is not fused into the keyframe map (a
  // rebuild still fuses it). DESIGN: the odometry check is what keeps
  // the drift visible to the graph; taking tracked motion for every
  // keyframe the closer was behind on left the synthetic loop at 7.0 cm
  // in real time instead of 1.5-1.9.
  const bool behind = shed || !pending_.empty();
  LoopKeyframe& kf = current_;
  // Made before the frontend applied the corrections sent since: in the
  // frame before them.
  counters_.late_keyframes += kf.epoch < corrections_.size();
  for (uint64_t e = kf.epoch; e < corrections_.size(); ++e) {
    kf.T_world_kf = corrections_[e] * kf.T_world_kf;
    kf.T_world_previous = corrections_[e] * kf.T_world_previous;
    kf.T_world_previous_color = corrections_[e] * kf.T_world_previous_color;
  }
  kf.observation.T_world_cam = kf.T_world_kf.cast<float>();
  ++counters_.keyframes;

  const alg::LoopClosureParams& lp = params_.loop;
  const uint32_t id = kf.id;
  const bool first = graph_.nodes().empty();
  graph_.setNode(id, kf.T_world_kf);
  if (std::exchange(fix_next_, false)) graph_.fixNode(id);
  if (!first && id > 0 && kf.previous && graph_.hasNode(id - 1)) {
    graph_.addFactor({id - 1, id, shed ? uncheckedOdometry(kf) : odometry(kf),
                      alg::isotropicInformation(lp.odometry_sigma_deg * M_PI / 180.0, lp.odometry_sigma_m), false});
  }
  observations_[id] = kf.observation;
  if (static_cast<int>(observations_.size()) > std::max(2, lp.max_stored_keyframes)) {
    // Thin the older half: every other one goes, the newest half stays whole.
    const size_t half = observations_.size() / 2;
    size_t k = 0;
    for (auto it = observations_.begin(); it != observations_.end() && k < half; ++k) {
      it = k % 2 == 1 ? observations_.erase(it) : std::next(it);
    }
  }
  database_.add(id, kf.features, kf.T_world_kf);

  if (kf.features.descriptors.rows == 0 || id < static_cast<uint32_t>(std::max(1, lp.min_keyframe_gap))) {
    finishKeyframe(!shed);
    return;
  }
  if (behind) {
    counters_.skipped += !shed;
    finishKeyframe(!shed);
    return;
  }
  ++counters_.queries;
  query_.emplace(database_, current_.features, camera_, kf.T_world_kf, counters_.queries - 1,
                 id - static_cast<uint32_t>(lp.min_keyframe_gap));
  confirmed_.reset();
  phase_ = Phase::kQuery;
}

void LoopCloser::finishKeyframe(bool fuse) {
  // Fused only now: the map a keyframe is checked against must not hold
  // that keyframe's own surfaces at its drifted pose.
  const auto t0 = std::chrono::steady_clock::now();
  if (fuse && observations_.count(current_.id)) {
    const alg::DepthObservation& o = observations_.at(current_.id);
    // What the keyframe sees comes back first (fusion would bring back
    // the blocks it reaches one by one anyway).
    bringBackView(o.T_world_cam.cast<double>());
    alg::integrate(map_, o, parallel_);
    keepWithinBudget(o.T_world_cam.cast<double>());
  }
  counters_.fuse_ms += msSince(t0);
  current_ = LoopKeyframe{};  // the frame's buffers go back
  candidates_.clear();
  phase_ = Phase::kIdle;
}

Eigen::Isometry3d LoopCloser::odometry(const LoopKeyframe& kf) {
  const Eigen::Isometry3d tracked = kf.T_world_previous.inverse() * kf.T_world_kf;
  const alg::PreprocessedFrame& previous = *kf.previous;
  if (previous.levels.empty() || kf.frame.levels.empty()) return tracked;
  const alg::PhotometricReference reference{&previous, kf.T_world_previous_color, kf.T_depth_color};
  alg::TrackingParams tp = params_.tracking;
  tp.photometric_scale_m = kf.photometric_scale_m;
  const alg::IcpResult icp = alg::trackPointToPlane(kf.frame, alg::frameAsModel(previous, kf.T_world_previous),
                                                    kf.T_world_kf, tp, reference, parallel_);
  if (!icp.ok) {
    ++counters_.odometry_unverified;
    return tracked;
  }
  // Tracking against the map is the more precise of the two while they
  // agree (the map averages many frames); when they do not, the tracked
  // motion holds a jump the two keyframes' own images do not show.
  const Eigen::Isometry3d aligned = kf.T_world_previous.inverse() * icp.T_world_cam;
  const Eigen::Isometry3d d = tracked.inverse() * aligned;
  const alg::LoopClosureParams& lp = params_.loop;
  if (!icp.degraded.empty() || (alg::translationNorm(d) <= lp.jump_sigmas * lp.odometry_sigma_m &&
                                 degrees(alg::rotationAngle(d)) <= lp.jump_sigmas * lp.odometry_sigma_deg)) {
    return tracked;
  }
  ++counters_.odometry_jumps;
  return aligned;
}

void LoopCloser::setBlockBacking(alg::BlockBacking* backing, size_t budget_bytes) {
  backing_ = budget_bytes > 0 ? backing : nullptr;
  budget_bytes_ = backing_ ? budget_bytes : 0;
  map_.setBacking(backing_);
}

void LoopCloser::bringBackView(const Eigen::Isometry3d& T_world_cam) {
  if (!backing_ || map_.blocksElsewhere().empty()) return;
  // DESIGN: on this thread, not the frontend's: waiting on the disk here
  // costs no frame its deadline.
  const uint64_t lost = map_.blocksLostInBacking(), back = map_.blocksTakenBack();
  for (const auto& [z, k] : budget::blocksOutInView(map_, T_world_cam.inverse().cast<float>(), camera_,
                                                    static_cast<float>(params_.tsdf.max_integration_depth_m))) {
    map_.findOrAllocate(alg::unpackBlockKey(k));
  }
  counters_.blocks_brought_back += map_.blocksTakenBack() - back;
  counters_.blocks_lost += map_.blocksLostInBacking() - lost;
}

void LoopCloser::keepWithinBudget(const Eigen::Isometry3d& T_world_cam) {
  if (!backing_) return;
  const size_t count = budget::blocksToMoveOut(map_.memory().bytes, budget_bytes_, std::numeric_limits<size_t>::max(),
                                               map_.blockCount());
  if (count > 0) {
    counters_.blocks_lost +=
        map_.removeBlocks(budget::farthestBlocks(map_, T_world_cam.inverse().cast<float>(), camera_,
                                                 static_cast<float>(params_.tsdf.max_integration_depth_m), count));
    counters_.blocks_moved_out += count;
  }
  counters_.map_bytes_max = std::max(counters_.map_bytes_max, map_.memory().bytes);
}

std::vector<alg::ModelView> LoopCloser::render(const alg::PreprocessedFrame& frame,
                                               const Eigen::Isometry3d& T_world_cam) {
  std::vector<alg::ModelView> model;
  const int levels = static_cast<int>(frame.levels.size());
  if (levels == 0) return model;
  bringBackView(T_world_cam);
  const int model_level = std::clamp(alg::modelLevel(params_.tracking, camera_.width), 0, levels - 1);
  const cv::Mat hint = model_level == 0 ? frame.depth_m : frame.levels[model_level].depth;
  model.push_back(alg::raycast(map_, camera_.level(model_level), T_world_cam.cast<float>(), params_.raycast, false,
                               parallel_, hint));
  for (int l = 1; l <= model_level && l < levels; ++l) model.push_back(model.back());
  while (static_cast<int>(model.size()) < levels) model.push_back(alg::subsampleView(model.back()));
  return model;
}

void LoopCloser::verifyNext() {
  // The two best candidates, one per step.
  if (next_candidate_ >= candidates_.size() || next_candidate_ >= 2) {
    finishKeyframe();
    return;
  }
  const alg::LoopClosureParams& lp = params_.loop;
  const alg::RelocalizationParams& rp = params_.relocalization;
  const alg::RelocalizationCandidate& c = candidates_[next_candidate_++];
  if (!graph_.hasNode(c.keyframe_id)) return;
  const Eigen::Isometry3d& T_world_kf = current_.T_world_kf;
  // Depth alone: with the map's colors rendered at the candidate as a
  // photometric reference, the synthetic loop's closures came out worse; a
  // view along one wall is kept from sliding by the factor's shape instead.
  const alg::IcpResult icp =
      alg::trackPointToPlane(current_.frame, render(current_.frame, c.T_world_cam), c.T_world_cam, params_.tracking, {},
                             parallel_);
  const Eigen::Isometry3d moved = c.T_world_cam.inverse() * icp.T_world_cam;
  const Eigen::Isometry3d correction = T_world_kf.inverse() * icp.T_world_cam;
  const double path = pathLength(c.keyframe_id, current_.id);
  if (alg::translationNorm(correction) > lp.max_drift_m + lp.max_drift_per_m * path ||
      degrees(alg::rotationAngle(correction)) > lp.max_drift_deg + lp.max_drift_deg_per_m * path) {
    ++counters_.refused_drift;
  } else if (icp.ok && icp.degraded.empty() && alg::translationNorm(moved) <= rp.max_icp_correction_m &&
             degrees(alg::rotationAngle(moved)) <= rp.max_icp_correction_deg) {
    confirmed_ = Confirmed{c, icp.T_world_cam, icp.information};
    phase_ = Phase::kSolve;
  } else {
    ++counters_.refused_icp;
  }
}

void LoopCloser::solve() {
  // The closure: the keyframe's pose as the old keyframe's part of the map
  // has it. Its information has the shape of ICP's: a view that constrains
  // one direction weakly (along a wall) gives a factor weak in that
  // direction.
  const alg::LoopClosureParams& lp = params_.loop;
  const uint32_t id = current_.id;
  const alg::RelocalizationCandidate& c = confirmed_->candidate;
  const Eigen::Isometry3d& T_loop = confirmed_->T_world_kf;
  const Eigen::Isometry3d correction = current_.T_world_kf.inverse() * T_loop;
  const alg::Matrix6d Ad = alg::adjoint(T_loop);  // to a right perturbation, in the keyframe's frame
  const alg::PoseGraphFactor factor{
      c.keyframe_id, id, graph_.node(c.keyframe_id).inverse() * T_loop,
      alg::shapedInformation(Ad.transpose() * confirmed_->information * Ad, lp.loop_sigma_deg * M_PI / 180.0,
                             lp.loop_sigma_m, lp.loop_min_information_ratio),
      true};
  const std::map<uint32_t, Eigen::Isometry3d> before = graph_.nodes();
  const alg::PoseGraphReport report = graph_.addLoop(factor, before.begin()->first, std::sqrt(lp.gate_chi2));
  if (report.refused) {
    ++counters_.refused_graph;
    spdlog::info("keyframe {}: loop with keyframe {} refused by the pose graph (whitened error {:.1f} > {:.1f}{})", id,
                 c.keyframe_id, report.max_whitened_error, std::sqrt(lp.gate_chi2),
                 report.failure.empty() ? "" : "; " + report.failure);
    finishKeyframe();
    return;
  }
  // Applied only when the solution moves some keyframe beyond
  // min_correction; otherwise the factor stays and the nodes as they were.
  const auto [moved_m, moved_deg] = largestMove(before, graph_.nodes());
  if (moved_m < lp.min_correction_m && moved_deg < lp.min_correction_deg) {
    graph_.setNodes(before);
    ++counters_.consistent;
    finishKeyframe();
    return;
  }
  ++counters_.closures;
  counters_.cost_before += report.cost_before;
  counters_.cost_after += report.cost_after;
  counters_.largest_correction_m = std::max(counters_.largest_correction_m, moved_m);
  counters_.largest_correction_deg = std::max(counters_.largest_correction_deg, moved_deg);
  spdlog::info("keyframe {}: loop closed with keyframe {} ({} PnP inliers; {:.1f} cm / {:.2f} deg from the tracked "
               "pose); keyframes moved up to {:.1f} cm / {:.2f} deg, pose graph cost {:.1f} -> {:.1f}",
               id, c.keyframe_id, c.pnp_inliers, 100 * alg::translationNorm(correction),
               degrees(alg::rotationAngle(correction)), 100 * moved_m, moved_deg, report.cost_before,
               report.cost_after);
  // The graph's poses to the database and the observations; the map is
  // fused anew from them in steps.
  building_ = LoopCorrection{};
  building_.epoch = corrections_.size() + 1;
  building_.keyframe = id;
  building_.matched = c.keyframe_id;
  building_.nodes = graph_.nodes();
  const uint32_t newest = graph_.nodes().rbegin()->first;
  building_.newest = graph_.node(newest) * before.at(newest).inverse();
  for (const auto& [node, T] : graph_.nodes()) {
    database_.updatePose(node, T);
    auto obs = observations_.find(node);
    if (obs != observations_.end()) obs->second.T_world_cam = T.cast<float>();
  }
  if (base_) {
    rebuilt_.emplace(*base_);
  } else {
    rebuilt_.emplace(params_.tsdf);
  }
  rebuild_ids_.clear();
  for (const auto& [node, obs] : observations_) rebuild_ids_.push_back(node);
  rebuild_next_ = 0;
  current_ = LoopKeyframe{};
  candidates_.clear();
  phase_ = Phase::kRebuild;
}

void LoopCloser::rebuildStep() {
  for (int k = 0; k < std::max(1, params_.rebuild_step_keyframes) && rebuild_next_ < rebuild_ids_.size(); ++k) {
    const auto obs = observations_.find(rebuild_ids_[rebuild_next_++]);
    if (obs == observations_.end()) continue;
    alg::integrate(*rebuilt_, obs->second, parallel_);
    ++counters_.keyframes_rebuilt;
  }
  if (rebuild_next_ < rebuild_ids_.size()) return;
  map_ = std::move(*rebuilt_);
  rebuilt_.reset();
  building_.map = std::make_shared<alg::TsdfMap>(map_);
  if (backing_) {
    // The blocks out of memory were the old map's.
    backing_->clear();
    map_.setBacking(backing_);
    if (!rebuild_ids_.empty()) {
      if (const auto last = observations_.find(rebuild_ids_.back()); last != observations_.end()) {
        keepWithinBudget(last->second.T_world_cam.cast<double>());
      }
    }
  }
  corrections_.push_back(building_.newest);
  correction_ = std::move(building_);
  building_ = LoopCorrection{};
  phase_ = Phase::kIdle;
}

double LoopCloser::pathLength(uint32_t from, uint32_t to) const {
  double path = 0;
  const auto end = graph_.nodes().upper_bound(to);
  const Eigen::Isometry3d* previous = nullptr;
  for (auto it = graph_.nodes().lower_bound(from); it != end; ++it) {
    if (previous) path += (previous->translation() - it->second.translation()).norm();
    previous = &it->second;
  }
  return path;
}

std::pair<size_t, size_t> LoopCloser::observations() const {
  size_t bytes = 0;
  for (const auto& [id, o] : observations_) {
    bytes += o.depth_m.total() * o.depth_m.elemSize() + o.rgb.total() * o.rgb.elemSize() +
             o.confidence.total() * o.confidence.elemSize();
  }
  return {observations_.size(), bytes};
}

}  // namespace hxmap::rt
