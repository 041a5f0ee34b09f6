#include "hxmap/relocalization/keyframe_database.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/features2d.hpp>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

FrameFeatures extractFeatures(const cv::Mat& gray8, const cv::Mat& depth_m, const PinholeCamera& camera,
                              const RelocalizationParams& params, bool require_depth) {
  FrameFeatures out;
  if (gray8.empty() || gray8.type() != CV_8UC1) return out;
  cv::Ptr<cv::ORB> orb = cv::ORB::create(std::max(1, params.features), 1.2f, 8, 31, 0, 2, cv::ORB::HARRIS_SCORE, 31,
                                         std::clamp(params.fast_threshold, 1, 255));
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  orb->detectAndCompute(gray8, cv::noArray(), keypoints, descriptors);
  const bool have_depth = !depth_m.empty() && depth_m.type() == CV_32FC1 && depth_m.size() == gray8.size();
  std::vector<int> keep;
  keep.reserve(keypoints.size());
  for (size_t i = 0; i < keypoints.size(); ++i) {
    const cv::Point2f& pt = keypoints[i].pt;
    const int u = static_cast<int>(pt.x + 0.5f), v = static_cast<int>(pt.y + 0.5f);
    float z = 0.0f;
    if (have_depth && u >= 0 && v >= 0 && u < depth_m.cols && v < depth_m.rows) z = depth_m.at<float>(v, u);
    const bool valid = z > 0.0f && std::isfinite(z);
    if (require_depth && !valid) continue;
    out.pixels.push_back(pt);
    out.points_cam.push_back(valid ? camera.backproject(pt.x, pt.y, z) : Eigen::Vector3f::Zero());
    keep.push_back(static_cast<int>(i));
  }
  out.descriptors.create(static_cast<int>(keep.size()), descriptors.cols, CV_8U);
  for (size_t k = 0; k < keep.size(); ++k) descriptors.row(keep[k]).copyTo(out.descriptors.row(static_cast<int>(k)));
  return out;
}

void KeyframeDatabase::add(uint32_t id, const FrameFeatures& features, const Eigen::Isometry3d& T_world_cam) {
  if (features.descriptors.rows == 0) return;
  Keyframe e;
  e.id = id;
  e.T_world_cam = T_world_cam;
  e.descriptors = features.descriptors.clone();
  e.points_cam = features.points_cam;
  keyframes_.push_back(std::move(e));
  while (params_.max_keyframes > 0 && static_cast<int>(keyframes_.size()) > params_.max_keyframes) evictOne();
}

bool KeyframeDatabase::updatePose(uint32_t id, const Eigen::Isometry3d& T_world_cam) {
  for (Keyframe& e : keyframes_) {
    if (e.id == id) {
      e.T_world_cam = T_world_cam;  // points are kept in the camera frame
      return true;
    }
  }
  return false;
}

size_t KeyframeDatabase::bytes() const {
  size_t b = 0;
  for (const Keyframe& e : keyframes_) b += e.descriptors.total() + e.points_cam.size() * sizeof(Eigen::Vector3f);
  return b;
}

namespace {
// The two nearest train rows of each query row by Hamming distance (ORB's
// 32-byte descriptors): {best index, best distance, second distance}.
// DESIGN: a plain loop over 64-bit words; cv::BFMatcher::knnMatch took
// 8.6 ms per 800 x 800 keyframe pair here; with the CPU's popcount
// instruction (picked at load time) this loop is several times faster.
struct Nearest2 {
  int index = -1;
  int best = 1 << 30, second = 1 << 30;
};
HXMAP_POPCNT_CLONES std::vector<Nearest2> nearestTwo(const cv::Mat& query, const cv::Mat& train) {
  std::vector<Nearest2> out(static_cast<size_t>(query.rows));
  const int words = query.cols / 8;
  if (words == 0 || train.cols != query.cols) return out;
  for (int q = 0; q < query.rows; ++q) {
    const auto* a = reinterpret_cast<const uint64_t*>(query.ptr<uint8_t>(q));
    Nearest2& n = out[static_cast<size_t>(q)];
    for (int t = 0; t < train.rows; ++t) {
      const auto* b = reinterpret_cast<const uint64_t*>(train.ptr<uint8_t>(t));
      int d = 0;
      for (int w = 0; w < words; ++w) d += __builtin_popcountll(a[w] ^ b[w]);
      if (d < n.best) {
        n.second = n.best;
        n.best = d;
        n.index = t;
      } else if (d < n.second) {
        n.second = d;
      }
    }
  }
  return out;
}

// Pose distance for ranking: meters, plus 0.5 m per radian of rotation.
double poseDistance(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  const Eigen::Isometry3d d = a.inverse() * b;
  return d.translation().norm() + 0.5 * Eigen::AngleAxisd(d.linear()).angle();
}
}  // namespace

void KeyframeDatabase::evictOne() {
  // DESIGN: the keyframe with the nearest neighbour among the kept ones
  // goes (the most redundant view), never the newest: the database keeps
  // views spread over the places the camera has been, which relocalization
  // and loop closure need, rather than only the last minutes.
  size_t worst = 0;
  double worst_d = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i + 1 < keyframes_.size(); ++i) {
    double nearest = std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < keyframes_.size(); ++j) {
      if (j != i) nearest = std::min(nearest, poseDistance(keyframes_[i].T_world_cam, keyframes_[j].T_world_cam));
    }
    if (nearest < worst_d) {
      worst_d = nearest;
      worst = i;
    }
  }
  keyframes_.erase(keyframes_.begin() + static_cast<std::ptrdiff_t>(worst));
}

std::vector<RelocalizationCandidate> KeyframeDatabase::query(const FrameFeatures& frame, const PinholeCamera& camera,
                                                             const Eigen::Isometry3d& near, uint64_t round,
                                                             std::string* why, uint32_t max_id) const {
  KeyframeQuery q(*this, frame, camera, near, round, max_id);
  while (q.step()) {
  }
  return q.candidates(why);
}

KeyframeQuery::KeyframeQuery(const KeyframeDatabase& db, const FrameFeatures& frame, const PinholeCamera& camera,
                             const Eigen::Isometry3d& near, uint64_t round, uint32_t max_id)
    : db_(&db), frame_(&frame), K_(camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1) {
  const auto& keyframes = db.keyframes_;
  const RelocalizationParams& params = db.params_;
  auto fail = [&](std::string reason) {
    why_ = std::move(reason);
    done_ = true;
  };
  if (keyframes.empty()) {
    fail("no keyframes kept yet");
    return;
  }
  if (frame.descriptors.rows < params.min_matches) {
    fail("too few features in the frame (" + std::to_string(frame.descriptors.rows) + ")");
    return;
  }
  // Which keyframes: the nearest to `near`, then a turn of the rest.
  std::vector<size_t> order;
  for (size_t i = 0; i < keyframes.size(); ++i) {
    if (keyframes[i].id <= max_id) order.push_back(i);
  }
  eligible_ = order.size();
  if (order.empty()) {
    fail("no keyframe old enough");
    return;
  }
  if (params.candidates <= 0 || static_cast<int>(order.size()) <= params.candidates) {
    chosen_ = order;
    return;
  }
  std::vector<double> d(keyframes.size());
  for (size_t i : order) d[i] = poseDistance(near, keyframes[i].T_world_cam);
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return d[a] < d[b]; });
  const size_t nearest = static_cast<size_t>(params.candidates) / 2;
  chosen_.assign(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(nearest));
  const size_t rest = order.size() - nearest;
  const size_t turn = static_cast<size_t>(params.candidates) - nearest;
  for (size_t k = 0; k < turn && k < rest; ++k) chosen_.push_back(order[nearest + (round * turn + k) % rest]);
}

bool KeyframeQuery::step() {
  if (done_) return false;
  const RelocalizationParams& params = db_->params_;
  if (!pnp_phase_) {
    // Match one chosen keyframe; once all are matched, PnP runs on the ones
    // with the most matches (RANSAC is the costly part).
    if (next_match_ < chosen_.size()) {
      const size_t i = chosen_[next_match_++];
      const KeyframeDatabase::Keyframe& e = db_->keyframes_[i];
      const std::vector<Nearest2> nearest = nearestTwo(frame_->descriptors, e.descriptors);
      Matched m;
      m.index = i;
      for (size_t q = 0; q < nearest.size(); ++q) {
        const Nearest2& n = nearest[q];
        if (n.index < 0 || n.second >= (1 << 30) || n.best >= params.ratio_test * n.second) continue;
        const Eigen::Vector3f p = e.points_cam[static_cast<size_t>(n.index)];
        m.object.emplace_back(p.x(), p.y(), p.z());  // in the keyframe's camera frame
        m.image.push_back(frame_->pixels[q]);
      }
      best_matches_ = std::max(best_matches_, static_cast<int>(m.object.size()));
      if (static_cast<int>(m.object.size()) >= params.min_matches) matched_.push_back(std::move(m));
      return true;
    }
    std::sort(matched_.begin(), matched_.end(),
              [](const Matched& a, const Matched& b) { return a.object.size() > b.object.size(); });
    if (static_cast<int>(matched_.size()) > std::max(1, params.pnp_candidates)) {
      matched_.resize(static_cast<size_t>(std::max(1, params.pnp_candidates)));
    }
    pnp_phase_ = true;
  }
  if (next_pnp_ >= matched_.size()) {
    finish();
    return false;
  }
  const Matched& m = matched_[next_pnp_++];
  const KeyframeDatabase::Keyframe& e = db_->keyframes_[m.index];
  const int matches = static_cast<int>(m.object.size());
  cv::Mat rvec, tvec;
  std::vector<int> inliers;
  const bool ok = cv::solvePnPRansac(m.object, m.image, K_, cv::noArray(), rvec, tvec, false, params.pnp_iterations,
                                     static_cast<float>(params.pnp_reprojection_px), 0.99, inliers, cv::SOLVEPNP_EPNP);
  best_inliers_ = std::max(best_inliers_, static_cast<int>(inliers.size()));
  if (!ok || static_cast<int>(inliers.size()) < params.min_pnp_inliers) return true;
  // Refine on the inliers (Levenberg-Marquardt from the RANSAC pose).
  std::vector<cv::Point3f> obj_in;
  std::vector<cv::Point2f> img_in;
  for (int k : inliers) {
    obj_in.push_back(m.object[static_cast<size_t>(k)]);
    img_in.push_back(m.image[static_cast<size_t>(k)]);
  }
  cv::solvePnPRefineLM(obj_in, img_in, K_, cv::noArray(), rvec, tvec);
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d Re;
  cv::cv2eigen(R, Re);
  Eigen::Isometry3d T_cam_kf = Eigen::Isometry3d::Identity();  // keyframe camera -> frame camera
  T_cam_kf.linear() = Re;
  T_cam_kf.translation() = Eigen::Vector3d(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
  if (!T_cam_kf.matrix().allFinite()) return true;
  RelocalizationCandidate c;
  c.keyframe_id = e.id;
  c.T_world_cam = e.T_world_cam * T_cam_kf.inverse();
  c.matches = matches;
  c.pnp_inliers = static_cast<int>(inliers.size());
  out_.push_back(c);
  return true;
}

void KeyframeQuery::finish() {
  done_ = true;
  std::sort(out_.begin(), out_.end(), [](const auto& a, const auto& b) { return a.pnp_inliers > b.pnp_inliers; });
  if (out_.empty()) {
    why_ = "no keyframe agrees (" + std::to_string(chosen_.size()) + " of " + std::to_string(eligible_) +
           " matched; best " + std::to_string(best_matches_) + " matches, " + std::to_string(best_inliers_) +
           " PnP inliers)";
  }
}

const std::vector<RelocalizationCandidate>& KeyframeQuery::candidates(std::string* why) const {
  if (why && out_.empty()) *why = why_;
  return out_;
}

}  // namespace hxmap::alg
