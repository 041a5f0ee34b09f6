// The residual channels of the pose feedback (paper eq 12) for one pixel of
// one keyframe, with their Jacobians.
//
// Conventions: poses are T_world_cam; a pose is perturbed on the right (in
// the camera frame), T <- T * exp(xi), xi = (omega, v) ordered as in se3.hpp.
//
// Depth: r = D(p) - D^(p; T), where D^ is the depth at which pixel p's ray
// from pose T meets the surface (TSDF zero crossing, or the implicit field's
// surface). Its Jacobian comes from the ray-surface geometry: near the hit
// the surface is the plane through the hit point with the map's normal (the
// TSDF's or the field's gradient), and the depth of a ray-plane
// intersection moves with the camera as
//   dD^/dv = -n_c / (n_c . q),   dD^/domega = D^ (n_c x q) / (n_c . q),
// with q the pixel's ray at unit depth and n_c the normal in the camera.
//
// Photometric: r = I(p) - C^(p; T), where C^ is the map's intensity at the
// hit. The hit point s stays on the fixed map while the pose moves, so the
// residual is I(pi(T^-1 s)) - C(s), equal to eq 12 at the current pose, with
// the standard derivative dI/dT = grad I . dpi/dT.
#pragma once

#include <Eigen/Geometry>

#include "hxmap/geometry/camera.hpp"
#include "hxmap/geometry/se3.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

/// Where a pixel's ray meets a map surface.
struct SurfaceHit {
  double z = 0;                    ///< depth along the optical axis
  Eigen::Vector3d point_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal_world = Eigen::Vector3d::Zero();  ///< unit, facing the camera
  double intensity = 0;            ///< the map's color there as intensity 0..1
};

/// A fixed implicit surface over a box (a refined region's neural field).
class ImplicitSurface {
 public:
  virtual ~ImplicitSurface() = default;
  virtual const Eigen::AlignedBox3f& box() const = 0;
  /// The surface along origin + t * dir (dir unit) near t_hint: the hit's t,
  /// the unit normal (the field's gradient) and rgb (0..255).
  virtual bool intersect(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float t_hint, float& t,
                         Eigen::Vector3f& normal, Eigen::Vector3f& rgb) const = 0;
};

/// The pixel's ray at unit depth, q = K^-1 (u, v, 1).
inline Eigen::Vector3d pixelRay(const PinholeCamera& cam, double u, double v) {
  return {(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0};
}

/// The TSDF surface along pixel (u, v)'s ray from T near depth z_hint:
/// within a voxel of the hint, one Newton step on the trilinear field there
/// (its gradient is the normal); else bracketed by trilinear samples around
/// the hint (or marched within a truncation band of it), refined by
/// secants, normal from the trilinear gradient. False without a crossing, or at a more grazing angle than
/// max_incidence_deg.
bool castExplicit(BlockCache& cache, const TsdfMap& map, const PinholeCamera& cam, const Eigen::Isometry3d& T_world_cam,
                  double u, double v, double z_hint, double max_incidence_deg, SurfaceHit& hit);

/// The implicit surface along the same ray (the ray must meet its box).
bool castImplicit(const ImplicitSurface& surface, const PinholeCamera& cam, const Eigen::Isometry3d& T_world_cam,
                  double u, double v, double z_hint, double max_incidence_deg, SurfaceHit& hit);

/// Depth residual D - D^ and its Jacobian (d r / d xi).
double depthResidual(const PinholeCamera& cam, const Eigen::Isometry3d& T_world_cam, double u, double v,
                     double observed_depth, const SurfaceHit& hit, Vector6d& J);

/// |cos| of the angle between pixel (u, v)'s ray and the hit's normal.
double incidenceCosine(const PinholeCamera& cam, const Eigen::Isometry3d& T_world_cam, double u, double v,
                       const SurfaceHit& hit);

/// Photometric residual I(p) - C^ and its Jacobian; (gx, gy) is the
/// observed intensity's gradient at p per pixel.
double photoResidual(const PinholeCamera& cam, const Eigen::Isometry3d& T_world_cam, double u, double v,
                     double observed_intensity, double gx, double gy, const SurfaceHit& hit, Vector6d& J);

/// Relative-pose factor residual e = log(Z^-1 Ta^-1 Tb) for a measured
/// motion Z = Ta^-1 Tb, with its Jacobians for right perturbations of Ta and
/// Tb (first order in e: Ja = -Ad(Tb^-1 Ta), Jb = I).
Vector6d relativePoseResidual(const Eigen::Isometry3d& Z, const Eigen::Isometry3d& Ta, const Eigen::Isometry3d& Tb,
                              Matrix6d* Ja = nullptr, Matrix6d* Jb = nullptr);

/// Adjoint of T for (omega, v) tangents: T exp(xi) T^-1 = exp(Ad(T) xi).
Matrix6d adjoint(const Eigen::Isometry3d& T);

}  // namespace hxmap::alg
