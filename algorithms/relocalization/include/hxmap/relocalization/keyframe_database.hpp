// The keyframe database: per keyframe, ORB features with the 3D points
// their depth gives, for relocalization (a frame matched against the kept
// keyframes, its pose recovered with PnP + RANSAC) and, later, loop
// closure (the same matching against keyframes far back in time). Bounded:
// past max_keyframes, the keyframe nearest another kept one goes.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "hxmap/geometry/camera.hpp"
#include "hxmap/relocalization/params.hpp"

namespace hxmap::alg {


/// An image's ORB features with depth: keypoints, descriptors (CV_8U, 32
/// bytes per row) and camera-frame points (z > 0 where depth was valid;
/// features without depth are dropped).
struct FrameFeatures {
  std::vector<cv::Point2f> pixels;
  cv::Mat descriptors;
  std::vector<Eigen::Vector3f> points_cam;
};

/// ORB on an 8-bit gray image; depth (CV_32F meters, same size) backs each
/// feature with a 3D point, features without valid depth are left out
/// when `require_depth`.
FrameFeatures extractFeatures(const cv::Mat& gray8, const cv::Mat& depth_m, const PinholeCamera& camera,
                              const RelocalizationParams& params, bool require_depth = true);

/// What relocalization found for a frame.
struct RelocalizationCandidate {
  uint32_t keyframe_id = 0;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  int matches = 0;       ///< descriptor matches with that keyframe
  int pnp_inliers = 0;   ///< RANSAC consensus
};

class KeyframeQuery;

class KeyframeDatabase {
 public:
  explicit KeyframeDatabase(const RelocalizationParams& params = {}) : params_(params) {}

  /// Adds a keyframe (its features and pose; points go to the world).
  void add(uint32_t id, const FrameFeatures& features, const Eigen::Isometry3d& T_world_cam);
  /// A keyframe's pose moved (pose feedback, loop closure): its points move
  /// with it. False when the keyframe is not kept.
  bool updatePose(uint32_t id, const Eigen::Isometry3d& T_world_cam);

  /// Candidate poses for a frame, best first (most PnP inliers); empty when
  /// no keyframe gives min_pnp_inliers. `why` (optional) receives the
  /// reason when empty.
  /// `near` ranks the keyframes nearest it first; `round` (the count of
  /// attempts so far) picks which of the rest this attempt matches. Only
  /// keyframes with an id up to `max_id` take part (loop closure: the old
  /// ones).
  std::vector<RelocalizationCandidate> query(const FrameFeatures& frame, const PinholeCamera& camera,
                                             const Eigen::Isometry3d& near, uint64_t round,
                                             std::string* why = nullptr,
                                             uint32_t max_id = UINT32_MAX) const;

  /// A kept keyframe: its ORB descriptors (32 bytes a row) and their
  /// points in its camera frame.
  struct Keyframe {
    uint32_t id = 0;
    Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
    cv::Mat descriptors;
    std::vector<Eigen::Vector3f> points_cam;
  };
  /// Oldest first (what a map file saves; add() restores them in order).
  const std::vector<Keyframe>& keyframes() const { return keyframes_; }

  size_t size() const { return keyframes_.size(); }
  size_t bytes() const;
  const RelocalizationParams& params() const { return params_; }

 private:
  friend class KeyframeQuery;
  void evictOne();

  RelocalizationParams params_;
  std::vector<Keyframe> keyframes_;  ///< oldest first
};

/// One query of a database, run in steps (KeyframeDatabase::query runs
/// them all at once): each step matches one chosen keyframe's descriptors
/// or runs PnP + RANSAC on one matched keyframe, a few milliseconds each,
/// so a background thread can run one step per slice its scheduler admits.
/// The database must not change while a query on it is under way (one
/// thread owns both).
class KeyframeQuery {
 public:
  /// Arguments as KeyframeDatabase::query's.
  KeyframeQuery(const KeyframeDatabase& db, const FrameFeatures& frame, const PinholeCamera& camera,
                const Eigen::Isometry3d& near, uint64_t round, uint32_t max_id = UINT32_MAX);
  /// Runs the next step; false when nothing was left to run.
  bool step();
  bool done() const { return done_; }
  /// The candidates found, best first (final once done()); `why` receives
  /// the reason when there are none.
  const std::vector<RelocalizationCandidate>& candidates(std::string* why = nullptr) const;

 private:
  struct Matched {
    size_t index = 0;
    std::vector<cv::Point3f> object;
    std::vector<cv::Point2f> image;
  };
  void finish();

  const KeyframeDatabase* db_;
  const FrameFeatures* frame_;
  cv::Matx33d K_;
  std::vector<size_t> chosen_;  ///< database indices to match
  size_t eligible_ = 0;         ///< keyframes old enough
  size_t next_match_ = 0, next_pnp_ = 0;
  std::vector<Matched> matched_;
  bool pnp_phase_ = false, done_ = false;
  int best_matches_ = 0, best_inliers_ = 0;
  std::string why_;
  std::vector<RelocalizationCandidate> out_;
};

}  // namespace hxmap::alg
