// Confidence-weighted projective TSDF fusion (paper 3.1): each voxel of the
// blocks in the truncation band is projected into the depth image; the
// projective signed distance d = depth(u, v) - z is truncated to mu and fused
// with the pixel's confidence as weight (capped at max_weight), with color
// and running update statistics.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/camera.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

/// Inputs of one integration. depth_m CV_32F (0 = invalid), rgb CV_8UC3 or
/// empty, confidence CV_32F in [0, 1] or empty (then 1 everywhere), at the
/// depth's size or a pyramid level of it (then pixel (u, v) takes the
/// confidence of (u >> k, v >> k)).
struct DepthObservation {
  cv::Mat depth_m;
  cv::Mat rgb;
  cv::Mat confidence;
  PinholeCamera camera;
  Eigen::Isometry3f T_world_cam = Eigen::Isometry3f::Identity();
};

struct IntegrationStats {
  size_t blocks_in_band = 0;   ///< blocks the observation touched
  size_t blocks_allocated = 0; ///< newly allocated by it
  size_t voxels_updated = 0;
};

/// Pyramid level whose pixels fusion reads (every 2^level-th pixel of the
/// observation; TsdfParams::integration_level, or the automatic choice).
int integrationLevel(const TsdfMap& map, const PinholeCamera& camera);

/// Pixel stride (at the integration level) at which allocateBand samples the depth image
/// (TsdfParams::allocation_stride_px, or the automatic choice for 0).
/// `focal_px`: the smaller focal length, in pixels of that level.
int allocationStride(const TsdfMap& map, double focal_px);

/// Blocks whose voxels the observation can update; allocates missing ones.
std::vector<int32_t> allocateBand(TsdfMap& map, const DepthObservation& obs, size_t* newly_allocated = nullptr);

/// The optimized kernel (incremental transforms per block row, parallel over
/// blocks).
IntegrationStats integrate(TsdfMap& map, const DepthObservation& obs, const ParallelFor& parallel = serialFor);

/// Takes an observation fused earlier by integrate() back out of the map
/// (the same observation, the same pose: the voxels it updated get their
/// averages without it; exact below the weight cap, see removeObservation).
/// With integrate() at a corrected pose this re-integrates a frame whose
/// pose changed (pose feedback, paper 3.4). Blocks it leaves empty stay
/// allocated.
IntegrationStats deintegrate(TsdfMap& map, const DepthObservation& obs, const ParallelFor& parallel = serialFor);

/// Plain reference: the same rule written directly (double math, one voxel at
/// a time), used to test the optimized kernel.
IntegrationStats integrateReference(TsdfMap& map, const DepthObservation& obs);

}  // namespace hxmap::alg
