// Raycasting the TSDF into depth, vertex, normal and color images from any
// pose and at any pyramid level (pass camera.level(l)). Rays skip unallocated
// blocks whole, march by the SDF inside allocated ones, and locate the
// + to - zero crossing by interpolation of trilinear samples.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/camera.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

struct ModelView {
  PinholeCamera camera;
  Eigen::Isometry3f T_world_cam = Eigen::Isometry3f::Identity();
  cv::Mat depth;         ///< CV_32F z in the camera frame, 0 = no surface
  cv::Mat vertex_world;  ///< CV_32FC3
  cv::Mat normal_world;  ///< CV_32FC3 unit, facing the camera, or 0
  cv::Mat rgb;           ///< CV_8UC3, empty unless requested
  int valid_pixels = 0;
};

/// `depth_hint` (optional, CV_32F z in meters, camera-sized) predicts the
/// surface per pixel, e.g. the frame just fused at this pose: such rays
/// bracket it directly, or march from a truncation distance before it
/// instead of from the per-tile bound. 0 = no prediction (march); negative =
/// predicted empty, the ray is not cast (its pixel stays invalid).
ModelView raycast(const TsdfMap& map, const PinholeCamera& camera, const Eigen::Isometry3f& T_world_cam,
                  const RaycastParams& params, bool with_color = false, const ParallelFor& parallel = serialFor,
                  const cv::Mat& depth_hint = cv::Mat());

/// A coarser view by taking every second pixel (normals re-used), for
/// tracking pyramids without re-raycasting.
ModelView subsampleView(const ModelView& view);

}  // namespace hxmap::alg
