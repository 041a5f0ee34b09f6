// SE(3) helpers. Tangent vectors are ordered (omega, v): rotation first.
// Updates are left-multiplied: T <- exp(xi) * T.
#pragma once

#include <Eigen/Geometry>

namespace hxmap::alg {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

Eigen::Matrix3d skew(const Eigen::Vector3d& w);

/// Rotation from an axis-angle vector (Rodrigues).
Eigen::Matrix3d expSO3(const Eigen::Vector3d& omega);
Eigen::Vector3d logSO3(const Eigen::Matrix3d& R);

/// Exponential and logarithm of SE(3) with the full left Jacobian.
Eigen::Isometry3d expSE3(const Vector6d& xi);
/// An optical camera (z forward, x right, y down) held level, in a z-up
/// frame (REP 103: x forward, y left, z up) at its origin.
Eigen::Isometry3d levelOpticalInZUp();
/// A camera's optical frame on a robot base (REP 103/105: base x forward, z
/// up): the camera body at (x, y, z) m, turned by roll, pitch, yaw degrees
/// (about x, y, z; applied yaw first), optical axes (z forward, x right,
/// y down) on it. All zero: levelOpticalInZUp() at the base's origin.
Eigen::Isometry3d mountedOptical(const Eigen::Vector3d& xyz_m, const Eigen::Vector3d& rpy_deg);
Vector6d logSE3(const Eigen::Isometry3d& T);

/// Rotation angle of T in radians and translation length in meters.
double rotationAngle(const Eigen::Isometry3d& T);
double translationNorm(const Eigen::Isometry3d& T);

/// True when T's linear part is a proper rotation (orthonormal, det +1) within
/// `tolerance` and every entry is finite.
bool isRigid(const Eigen::Matrix4d& T, double tolerance = 1e-4);

/// Spherical interpolation between two poses, t in [0, 1].
Eigen::Isometry3d interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double t);

}  // namespace hxmap::alg
