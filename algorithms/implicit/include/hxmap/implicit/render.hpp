// Rendering a neural field along keyframe rays, confined to its box, and
// the training loss (paper 3.3, eq 10).
//
// Per ray: sphere tracing finds the field's first zero crossing; samples
// are placed around it and around the observed depth (both, when they
// disagree: the field must be able to grow a surface fusion erased and to
// clear one that is not there); opacities come from the signed distances by
// the NeuS rule alpha_i = max(0, 1 - Phi(s_{i+1} / b) / Phi(s_i / b)) with
// Phi the logistic function (unbiased for planar surfaces at any incidence);
// depth and color are alpha-composited. Rendered depth counts transmittance
// left after the last sample as a hit at the far end of the samples, so a
// ray whose samples cross no surface still pulls opacity towards the
// observed depth.
//
// Loss = lambda_p photo + lambda_d depth + lambda_n normal + lambda_e eikonal:
// Huber on color and on depth (in voxels); normal consistency 1 - cos
// between the field's gradient and the keyframe's measured normal at the
// traced surface; eikonal (|grad s| - 1)^2. Gradients of s in space are
// central differences (half a voxel), so the regularizers need forward
// values only and backpropagate like any other sample.
//
// DESIGN: "explicit normals" are taken from the keyframe's depth map
// (the normals the frontend computes for tracking), not from the TSDF: the
// TSDF's normals are what fusion got wrong at edges and on thin parts, the
// places refinement is for.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "hxmap/geometry/camera.hpp"
#include "hxmap/implicit/neural_field.hpp"
#include "hxmap/implicit/params.hpp"

namespace hxmap::alg {

/// The phases of a refinement job, for measuring where its time goes.
enum class RefinePhase {
  kOutside,      ///< not in the job (between slices)
  kPrepare,      ///< rendering the TSDF to measure its error and bias
  kTrace,        ///< sphere tracing the field along the batch's rays
  kSample,       ///< placing the samples and regularizer points
  kForward,      ///< the field at every sample
  kRender,       ///< compositing and the loss, with its gradient
  kBackward,     ///< the field's backward pass
  kOptimizer,    ///< Adam
  kBookkeeping,  ///< what was seen, the cells' errors, convergence
  kWriteBack,    ///< result(): the patch, sigma_Neural, the detail layer
};
inline constexpr int kRefinePhases = 10;
const char* refinePhaseName(RefinePhase phase);

/// Told each time a job moves to another phase (algorithms keep no clocks:
/// the caller's probe timestamps). Null everywhere by default.
class RefineProbe {
 public:
  virtual ~RefineProbe() = default;
  virtual void enter(RefinePhase phase) = 0;
};
inline void enterPhase(RefineProbe* probe, RefinePhase phase) {
  if (probe) probe->enter(phase);
}

/// A keyframe's images at the resolution refinement uses.
struct KeyframeImages {
  uint32_t id = 0;
  PinholeCamera camera;
  Eigen::Isometry3f T_world_cam = Eigen::Isometry3f::Identity();
  cv::Mat depth;   ///< CV_32F meters, 0 = none
  cv::Mat rgb;     ///< CV_8UC3 (same channel order as the map's colors), or empty
  cv::Mat normal;  ///< CV_32FC3 camera-frame unit normals (0 = none), or empty
};

/// A keyframe pixel whose observed surface lies in the field's box, or
/// beyond it (free_space: the ray crosses the box through empty space).
struct TrainingRay {
  Eigen::Vector3f origin = Eigen::Vector3f::Zero();
  Eigen::Vector3f dir = Eigen::Vector3f::UnitZ();  ///< unit
  float t_in = 0, t_out = 0;                       ///< the ray inside the box
  float t_obs = 0;                                 ///< observed surface distance along the ray
  Eigen::Vector3f rgb = Eigen::Vector3f::Zero();
  Eigen::Vector3f normal = Eigen::Vector3f::Zero();  ///< world frame, 0 = unknown
  bool has_color = false;
  bool free_space = false;  ///< t_obs lies beyond the box: no surface inside
  uint32_t keyframe = 0;
};

/// Rays of the keyframes' pixels (every pixel_stride-th) whose depth lands
/// in `box`, at most params.max_rays (an even spread when more). With
/// `keep_free`, then the rays that cross the box and observe a surface
/// beyond it (past t_out by more than twice the sample band) that
/// `keep_free` accepts, at most params.free_space_rays (an even spread).
std::vector<TrainingRay> collectRays(const std::vector<KeyframeImages>& keyframes, const Eigen::AlignedBox3f& box,
                                     const ImplicitParams& params,
                                     const std::function<bool(const TrainingRay&)>& keep_free = {});

/// The first zero crossing of the field along each ray in [t_in, t_out]
/// (sphere tracing, a sign change refined linearly); -1 when none, or when
/// the ray enters the box inside the surface. `scratch` (optional): the
/// field's buffers, reused.
std::vector<float> sphereTrace(const NeuralField& field, const std::vector<TrainingRay>& rays,
                               const std::vector<int32_t>& which, int max_steps, NeuralField::Cache* scratch = nullptr);

/// The samples of one iteration.
struct RenderBatch {
  std::vector<int32_t> rays;                 ///< indices into the candidate rays
  int samples = 0;                           ///< per ray
  std::vector<float> t;                      ///< rays.size() * samples, ascending per ray
  std::vector<Eigen::Vector3f> reg_points;   ///< normal / eikonal points
  std::vector<Eigen::Vector3f> reg_normals;  ///< measured normal at each, 0 = eikonal only
};

/// `which` rays (all candidate rays when empty: rays_per_iteration drawn at
/// random), traced and sampled; `jitter` stratifies the samples randomly
/// (training), else at stratum centers (evaluation). `rng` advances.
/// `scratch` as for sphereTrace.
RenderBatch sampleBatch(const NeuralField& field, const std::vector<TrainingRay>& rays, std::vector<int32_t> which,
                        const ImplicitParams& params, bool jitter, uint64_t& rng, RefineProbe* probe = nullptr,
                        NeuralField::Cache* scratch = nullptr);

struct LossTerms {
  double photo = 0, depth = 0, normal = 0, eikonal = 0;
  double total = 0;  ///< weighted (eq 10)
  int rays = 0, photo_rays = 0, normal_points = 0, reg_points = 0;
};

/// What a rendering produced besides the loss.
struct Rendering {
  std::vector<float> depth;          ///< per ray: composited distance along the ray
  std::vector<float> transmittance;  ///< per sample: light reaching it (1 = in front of every surface)
};

/// Renders the batch and evaluates the loss. With `grad` (size of the
/// field's parameters), adds dL/dparameters and adds the grid nodes it
/// touched to `touched` (begun by the caller). `rendering` (optional) receives depths and transmittances.
/// `cache` (optional): the field's buffers, reused; after the call it
/// holds the forward pass of the batch's samples and regularizer points
/// (samples first, in the batch's order).
LossTerms evaluateLoss(const NeuralField& field, const std::vector<TrainingRay>& rays, const RenderBatch& batch,
                       const ImplicitParams& params, std::vector<float>* grad = nullptr,
                       TouchedNodes* touched = nullptr, Rendering* rendering = nullptr, RefineProbe* probe = nullptr,
                       NeuralField::Cache* cache = nullptr);

}  // namespace hxmap::alg
