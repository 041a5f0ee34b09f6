// Sliding-window pose optimization (paper 3.4, eq 12-13) as a small factor
// graph over the poses of the last N keyframes:
//   - residual factors per keyframe: explicit photometric and depth against
//     the TSDF raycast from its pose, implicit photometric and depth against
//     the neural fields of refined regions (where the ray meets one), on the
//     pixel set Omega_j, Huber-weighted and scaled by the channel's lambda;
//   - relative-pose factors between consecutive keyframes: the motion
//     tracking measured, with information from the ICP Hessian;
//   - a Gaussian prior on the oldest pose, left by marginalizing the
//     keyframes that slid out (Schur complement of their factors).
// Levenberg-Marquardt with analytic Jacobians (residuals.hpp) solves it; the
// maps are fixed during a solve. Pure: no threads or clocks; the caller
// bounds the work with params.iterations and a stop callback.
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "hxmap/feedback/params.hpp"
#include "hxmap/feedback/residuals.hpp"
#include "hxmap/geometry/camera.hpp"
#include "hxmap/geometry/se3.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

/// A keyframe as the window needs it.
struct WindowKeyframe {
  uint32_t id = 0;
  int64_t stamp_ns = 0;
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();  ///< the estimate (tracking's at first)
  PinholeCamera camera;   ///< of the images below
  cv::Mat intensity;      ///< CV_32F 0..1
  cv::Mat depth;          ///< CV_32F meters, 0 = none
  /// Tracking's relative motion from the previous keyframe (T_prev^-1 T_this
  /// as tracked) and its information in this keyframe's camera frame
  /// (right-perturbation coordinates); zero information = no factor.
  Eigen::Isometry3d odometry_from_previous = Eigen::Isometry3d::Identity();
  Matrix6d odometry_information = Matrix6d::Zero();
};

/// The maps the residuals are taken against; both fixed during a solve.
struct FeedbackMaps {
  const TsdfMap* tsdf = nullptr;
  std::vector<const ImplicitSurface*> implicit;
};

/// Residual counts and robust costs per channel, summed over the window.
struct ChannelStats {
  int photo_explicit = 0, depth_explicit = 0, photo_implicit = 0, depth_implicit = 0;
  double cost = 0;  ///< the whole objective (residual factors, relative factors, prior)
};

struct SolveReport {
  int iterations = 0, accepted = 0;
  int evaluations = 0;      ///< residual evaluations (pixel set x keyframes)
  ChannelStats before, after;
  /// The objective on the fixed base pixel sets (with the relative factors
  /// and the prior) at the starting and the final poses: comparable, unlike
  /// before/after, whose top and explore sets change.
  double base_cost_before = 0, base_cost_after = 0;
  /// Per keyframe (window order): the information of its pose at the
  /// solution, the others marginalized ((H^-1)_jj^-1), to test whether a
  /// correction stands out of the solve's own noise.
  std::vector<Matrix6d> marginal_information;
  /// Per keyframe: neither its depth nor its photometric cost on the base
  /// pixels rose from the starting poses to the solution.
  std::vector<bool> channels_agree;
  bool stopped = false;     ///< the stop callback ended it early
  std::vector<Eigen::Isometry3d> poses_before;  ///< window order
  std::string failure;      ///< empty when the solve ran
};

class PoseWindow {
 public:
  explicit PoseWindow(const FeedbackParams& params);

  /// Appends a keyframe (its pose from tracking). When the window is full,
  /// the oldest keyframe is marginalized first: its factors, linearized at
  /// the current estimates against `maps`, become a prior on the next one.
  void add(WindowKeyframe keyframe, const FeedbackMaps& maps);

  /// Levenberg-Marquardt over the window's poses. `stop` (optional) is
  /// asked before each keyframe's cast into the maps (the costly part; a
  /// step on the tangent planes of the last cast is not interrupted): true
  /// ends the solve with the last accepted poses.
  SolveReport solve(const FeedbackMaps& maps, const std::function<bool()>& stop = {});

  const std::vector<WindowKeyframe>& keyframes() const { return keyframes_; }
  size_t size() const { return keyframes_.size(); }
  bool hasPrior() const { return has_prior_; }
  /// The prior on the oldest pose: information and gradient at prior_T_lin.
  const Matrix6d& priorInformation() const { return prior_H_; }
  const Vector6d& priorGradient() const { return prior_b_; }
  /// The uniform base pixel set of keyframe j (image coordinates).
  const std::vector<Eigen::Vector2i>& basePixels(size_t j) const { return slots_[j].base; }
  const FeedbackParams& params() const { return params_; }
  /// LM iterations of the next solves (the scheduler's effort level).
  void setIterations(int n) { params_.iterations = std::max(1, n); }

  /// A correction checked on a dense pixel grid (every params.verify_stride-th
  /// usable pixel of keyframe j, in both directions) rather than the
  /// window's samples: depth and photometric costs at the pose the frontend
  /// has (`from`) and at the window's (`to`), cast afresh at each. A
  /// residual beyond its gate at one pose and not the other counts as one
  /// at the gate, so that a pose cannot lower its cost by losing residuals.
  struct Verification {
    int pixels = 0;
    double depth_from = 0, depth_to = 0, photo_from = 0, photo_to = 0;
    bool passed = false;   ///< neither cost rose
    bool stopped = false;  ///< `stop` ended it (not passed)
  };
  /// `stop` (optional) is asked before each chunk of a window keyframe's
  /// size, as the solve asks before each cast.
  Verification verify(size_t j, const Eigen::Isometry3d& from, const Eigen::Isometry3d& to, const FeedbackMaps& maps,
                      const std::function<bool()>& stop = {}) const;

  /// Keyframe j's residual factor at pose T on `pixels` (u, v at the
  /// image level): 0.5 sum w r^2, and the Gauss-Newton H and b (d cost /
  /// d xi = b). Exposed for tests and the marginalization.
  struct PixelResult {
    float residual = 0;  ///< largest weighted |r| over the channels (for Omega's top set)
    float hint_z = 0;    ///< the explicit hit depth, the next evaluation's hint
  };
  struct Linearization {
    Matrix6d H = Matrix6d::Zero();
    Vector6d b = Vector6d::Zero();
    double cost = 0;
    double depth_cost = 0, photo_cost = 0;  ///< the cost's depth and photometric shares
    ChannelStats counts;
  };
  Linearization linearize(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps,
                          const std::vector<Eigen::Vector2i>& pixels, std::vector<PixelResult>* out = nullptr) const;
  /// The same factor at pose T from rays cast at T_cast: on the tangent
  /// planes of those hits, as the solve's steps between casts see it.
  /// (`repeat` > 1 evaluates the planes that many times: for benchmarks.)
  Linearization linearizeOnPlanes(size_t j, const Eigen::Isometry3d& T_cast, const Eigen::Isometry3d& T_world_kf,
                                  const FeedbackMaps& maps, const std::vector<Eigen::Vector2i>& pixels,
                                  int repeat = 1) const;

 private:
  /// What a residual reads of its pixel, packed. DESIGN: gathered once per
  /// pixel set instead of read from four images per evaluation: the pixels
  /// are scattered over 8 keyframes' images (about 10 MB at 320x240), and
  /// those reads, cache misses nearly all, were a quarter of the solve.
  struct PixelSample {
    int u = 0, v = 0;
    float depth = 0, intensity = 0, gx = 0, gy = 0;
  };
  std::vector<PixelSample> gather(size_t j, const std::vector<Eigen::Vector2i>& pixels) const;
  /// A ray's hit as the linearization saw it: the surface's tangent plane
  /// (point, normal) and color, the sample it belongs to, the channel.
  struct CachedHit {
    uint32_t sample = 0;
    bool implicit = false;
    float cosine = 1;  ///< point-to-plane scale, fixed at the linearization
    Eigen::Vector3d point_world, normal_world;
    double intensity = 0;
  };
  /// Casts the rays (TSDF, and the fields where they exist); `hits` (optional) receives what was hit.
  Linearization linearizeSamples(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps,
                                 const std::vector<PixelSample>& samples, std::vector<PixelResult>* out,
                                 std::vector<CachedHit>* hits = nullptr) const;
  /// The same factor at pose T from hits cast at a nearby pose: depth to
  /// their tangent planes, photometric at the hit points' projections
  /// (the model the Jacobians describe). No map access.
  Linearization linearizeCached(size_t j, const Eigen::Isometry3d& T_world_kf, const std::vector<PixelSample>& samples,
                                const std::vector<CachedHit>& hits, std::vector<PixelResult>* out) const;
  struct Slot {
    std::vector<Eigen::Vector2i> base;   ///< uniform over pixels with depth
    std::vector<Eigen::Vector2i> extra;  ///< top + explore of this iteration
    std::vector<PixelSample> base_samples, extra_samples;  ///< the same, gathered
    /// The base pixels' hits of the last cast of an earlier solve (world
    /// frame tangent planes): the next solve starts from them.
    std::shared_ptr<const std::vector<CachedHit>> base_hits;
    cv::Mat intensity;                   ///< blurred to the map's color resolution
    cv::Mat grad_x, grad_y;              ///< its gradient per pixel
    cv::Mat usable;                      ///< CV_8U: 1 where a pixel may join Omega
  };
  void prepare(Slot& slot, const WindowKeyframe& kf) const;
  /// A relative factor joins keyframe k to k-1.
  bool linked(size_t k) const {
    return params_.odometry_information_scale > 0 && !keyframes_[k].odometry_information.isZero(0);
  }
  void marginalizeOldest(const FeedbackMaps& maps);
  /// Relative factor between keyframes a and a+1 at poses Ta, Tb: cost,
  /// and its 12x12 H and b over (xi_a, xi_b).
  double relativeFactor(size_t a, const Eigen::Isometry3d& Ta, const Eigen::Isometry3d& Tb,
                        Eigen::Matrix<double, 12, 12>* H, Eigen::Matrix<double, 12, 1>* b) const;
  double priorCost(const Eigen::Isometry3d& T_world_kf, Matrix6d* H, Vector6d* b) const;

  // The solve's steps.
  /// Keyframe j's factors in a solve: base and extra pixel sets, and the
  /// hits they were cast on (shared by the trial steps that reuse them).
  struct KfEval {
    Linearization base, extra;
    std::vector<PixelResult> extra_pixels;
    std::shared_ptr<const std::vector<CachedHit>> base_hits, extra_hits;
  };
  /// Appends params_.explore_pixels random usable pixels of keyframe j.
  void explore(size_t j, std::vector<Eigen::Vector2i>& extra);
  /// Casts keyframe j's base (extra) samples into the maps at T_world_kf.
  void castBase(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps, KfEval& e) const;
  void castExtra(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps, KfEval& e) const;
  /// Keyframe j's factors at T_world_kf on the planes of `from`'s hits (no casting).
  KfEval onPlanes(size_t j, const Eigen::Isometry3d& T_world_kf, const KfEval& from) const;
  /// The whole objective at poses x; with H, b its normal equations.
  double assemble(const std::vector<Eigen::Isometry3d>& x, const std::vector<KfEval>& ev, Eigen::MatrixXd* H,
                  Eigen::VectorXd* b, ChannelStats& stats) const;
  /// The objective on the base sets alone (the extras' share left out).
  double baseCost(const std::vector<Eigen::Isometry3d>& x, const std::vector<KfEval>& ev) const;
  /// Omega for the next iteration of keyframe j at its accepted pose: the
  /// largest residuals among the extras, a fresh explore set, cast (the
  /// base too when `recast`; true if it was).
  bool nextPixelSets(size_t j, const Eigen::Isometry3d& T_world_kf, const FeedbackMaps& maps, bool recast, KfEval& e);
  /// Each pose's information with the others marginalized, from the window's H.
  std::vector<Matrix6d> marginalInformation(const Eigen::MatrixXd& H) const;

  FeedbackParams params_;
  std::vector<WindowKeyframe> keyframes_;
  std::vector<Slot> slots_;
  // Prior on keyframes_[0] from marginalization: cost(delta) =
  // 0.5 delta^T H delta + b^T delta, delta = log(T_lin^-1 T).
  bool has_prior_ = false;
  Eigen::Isometry3d prior_T_lin_ = Eigen::Isometry3d::Identity();
  Matrix6d prior_H_ = Matrix6d::Zero();
  Vector6d prior_b_ = Vector6d::Zero();
  uint64_t rng_state_;
};

}  // namespace hxmap::alg
