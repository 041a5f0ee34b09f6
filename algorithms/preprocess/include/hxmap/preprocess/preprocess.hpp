// Frame preprocessing for tracking and fusion: depth in meters (invalid = 0,
// NaN/inf/negative and out-of-range values removed), edge-preserving denoise,
// vertex and normal maps over a pyramid, per-pixel confidence, and intensity
// normalized to [0, 1] for photometric terms. Pure function of its inputs.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "hxmap/core/frame.hpp"
#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/camera.hpp"
#include "hxmap/preprocess/params.hpp"

namespace hxmap::alg {

/// One pyramid level, camera frame. Invalid pixels have depth 0, vertex z 0
/// and a zero normal. Levels finer than PreprocessParams::finest_level hold
/// only camera and depth (range-gated, not denoised); the other maps are empty.
struct FrameLevel {
  PinholeCamera camera;
  cv::Mat depth;       ///< CV_32F meters (denoised)
  cv::Mat vertex;      ///< CV_32FC3 camera-frame points
  cv::Mat normal;      ///< CV_32FC3 unit normals facing the camera, or 0
  cv::Mat confidence;  ///< CV_32F in [0, 1]
  cv::Mat intensity;   ///< CV_32F in [0, 1]
  /// CV_32FC3: intensity and its gradient per pixel (3x3 Sobel / 8),
  /// interleaved so that a bilinear lookup of all three reads 4 places.
  cv::Mat intensity_grad;
};

struct PreprocessedFrame {
  int64_t stamp_ns = 0;        ///< the color image's
  int64_t depth_stamp_ns = 0;  ///< the depth image's (== stamp_ns when synchronized)
  uint64_t seq = 0;
  cv::Mat depth_m;     ///< CV_32F, range-gated raw depth (what is fused)
  cv::Mat rgb;         ///< CV_8UC3
  cv::Mat intensity;   ///< CV_32F in [0, 1]
  std::vector<FrameLevel> levels;  ///< levels[0] is full resolution
  int finest = 0;                  ///< first level with normals and confidence
  bool has_color = false;          ///< false: rgb/intensity are black placeholders
  int valid_pixels = 0;            ///< valid depth pixels at level 0
  int rejected_pixels = 0;         ///< non-finite, negative or out-of-range depth removed
};

/// sigma(z) of the sensor noise model in meters.
inline float depthSigma(float z_m, const PreprocessParams& p) {
  const float d = z_m - 0.4f;
  return static_cast<float>(p.noise_sigma_a_m) + static_cast<float>(p.noise_sigma_b_per_m) * d * d;
}

/// frame.depth must be CV_32FC1 and frame.rgb CV_8UC3, both camera-sized;
/// anything else gives a frame with no valid pixels (the caller reports it).
/// `parallel` splits the row loops of the heavier filters (same result for
/// any ParallelFor).
PreprocessedFrame preprocessFrame(const RgbdFrame& frame, const PinholeCamera& camera, const PreprocessParams& params,
                                  const ParallelFor& parallel = serialFor);

/// Edge-preserving denoise of a depth map: per valid pixel, the mean of its
/// valid neighbours within bilateral_radius_px, weighted by a Gaussian of the
/// pixel distance (bilateral_sigma_px) and one of the depth difference
/// (bilateral_sigma_depth_factor times the sensor sigma at the pixel), cut at
/// 3 range sigmas. Invalid pixels stay 0.
cv::Mat bilateralDepth(const cv::Mat& depth, const PreprocessParams& params, const ParallelFor& parallel = serialFor);

/// Camera-frame normals from a vertex map (central differences); pixels whose
/// neighbours are invalid or jump by more than `max_jump(z)` get 0.
cv::Mat computeNormals(const cv::Mat& vertex, const PreprocessParams& params);

/// Half-resolution depth: per 2x2 block, the mean of the valid values close to
/// the block's nearest one (does not blend foreground with background).
cv::Mat downsampleDepth(const cv::Mat& depth, const PreprocessParams& params);

/// Half-resolution depth without a bias: per 2x2 block, the mean of the
/// four values when they agree within 3 %, else 0 (none). DESIGN:
/// downsampleDepth keeps the values near the block's nearest one, right for
/// edges but biased towards the camera where the noise exceeds the sensor
/// model (on the quality room's 4x-noise patch its level sat 2.5 cm in front
/// of the fused surface); ROI refinement, which compares keyframes with
/// the fused map, needs the unbiased mean.
cv::Mat averageDepth2x2(const cv::Mat& depth);

cv::Mat vertexMap(const cv::Mat& depth, const PinholeCamera& camera);

}  // namespace hxmap::alg
