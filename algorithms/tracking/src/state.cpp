#include "hxmap/tracking/state.hpp"

#include <algorithm>
#include <vector>

namespace hxmap::alg {

const char* trackingStateName(TrackingState state) {
  switch (state) {
    case TrackingState::kTracked:
      return "tracked";
    case TrackingState::kDegraded:
      return "degraded";
    case TrackingState::kLost:
      return "lost";
  }
  return "?";
}

const char* poseSourceName(PoseSource source) {
  switch (source) {
    case PoseSource::kNone:
      return "none";
    case PoseSource::kModel:
      return "model";
    case PoseSource::kOdometry:
      return "frame-to-frame";
    case PoseSource::kRelocalization:
      return "relocalization";
    case PoseSource::kGiven:
      return "given";
  }
  return "?";
}

TrackingDecision TrackingStateMachine::start() {
  TrackingDecision d;
  d.state = TrackingState::kTracked;
  d.source = PoseSource::kModel;
  d.fuse = true;
  return finish(d);
}

TrackingParams TrackingStateMachine::gates(const TrackingParams& params) const {
  TrackingParams p = params;
  if (consistent_.empty()) {
    // The map is one frame old: its noise is the frame's own, untested.
    p.min_consistent_ratio = p.min_consistent_ratio_lost;
    return p;
  }
  std::vector<double> v(consistent_.begin(), consistent_.end());
  auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  const double typical = *mid;
  p.min_consistent_ratio = std::min(p.min_consistent_ratio, p.typical_share_fused * typical);
  p.min_consistent_ratio_lost = std::min(p.min_consistent_ratio_lost, p.typical_share_lost * typical);
  return p;
}

void TrackingStateMachine::observe(double consistent_ratio, int window) {
  consistent_.push_back(consistent_ratio);
  while (static_cast<int>(consistent_.size()) > std::max(1, window)) consistent_.pop_front();
}

TrackingDecision TrackingStateMachine::given() {
  TrackingDecision d;
  d.state = TrackingState::kTracked;
  d.source = PoseSource::kGiven;
  d.fuse = true;
  return finish(d);
}

TrackingDecision TrackingStateMachine::update(const TrackingAttempts& a) {
  TrackingDecision d;
  if (!a.enough_depth) {
    d.reason = "too little valid depth";
    return finish(d);
  }
  if (a.relocalization && a.relocalization->ok) {
    // Verified against the model at the recovered pose; the next frame is
    // fused once the model confirms it again.
    d.state = a.relocalization->degraded.empty() ? TrackingState::kTracked : TrackingState::kDegraded;
    d.source = PoseSource::kRelocalization;
    d.reason = a.relocalization->degraded.empty() ? "" : "relocalized: " + a.relocalization->degraded;
    return finish(d);
  }
  // Lost, the pose is stale: a model result that agrees only in part may
  // be a wrong basin (it creeps towards the gate frame by frame), so only
  // one within the noise gates ends the loss.
  const bool model_usable = a.model && a.model->ok && (state_ != TrackingState::kLost || a.model->degraded.empty());
  if (model_usable) {
    d.source = PoseSource::kModel;
    if (a.model->degraded.empty()) {
      d.state = TrackingState::kTracked;
      d.fuse = true;
    } else {
      d.state = TrackingState::kDegraded;
      d.reason = a.model->degraded;
    }
    return finish(d);
  }
  const std::string model_failure = !a.model                ? std::string("model not tried")
                                    : a.model->ok              ? "agrees only in part while lost (" + a.model->degraded + ")"
                                                               : a.model->failure;
  if (state_ != TrackingState::kLost && a.odometry && a.odometry->ok) {
    d.state = TrackingState::kDegraded;
    d.source = PoseSource::kOdometry;
    d.reason = "model: " + model_failure + "; followed frame to frame";
    return finish(d);
  }
  d.reason = "model: " + model_failure;
  if (a.odometry) d.reason += "; frame to frame: " + a.odometry->failure;
  return finish(d);
}

TrackingDecision TrackingStateMachine::finish(TrackingDecision d) {
  if (d.state == TrackingState::kLost) {
    if (state_ != TrackingState::kLost || (counts_.tracked + counts_.degraded + counts_.lost) == 0) {
      ++counts_.lost_episodes;
    }
    ++counts_.lost;
    ++lost_run_;
    counts_.longest_lost_run = std::max(counts_.longest_lost_run, lost_run_);
  } else {
    lost_run_ = 0;
    ++(d.state == TrackingState::kTracked ? counts_.tracked : counts_.degraded);
    counts_.odometry_frames += d.source == PoseSource::kOdometry;
    counts_.relocalized += d.source == PoseSource::kRelocalization;
  }
  state_ = d.state;
  return d;
}

}  // namespace hxmap::alg
