#include "hxmap/geometry/se3.hpp"

#include <cmath>

namespace hxmap::alg {

Eigen::Matrix3d skew(const Eigen::Vector3d& w) {
  Eigen::Matrix3d S;
  S << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  return S;
}

Eigen::Matrix3d expSO3(const Eigen::Vector3d& omega) {
  const double theta = omega.norm();
  if (theta < 1e-12) return Eigen::Matrix3d::Identity() + skew(omega);
  return Eigen::AngleAxisd(theta, omega / theta).toRotationMatrix();
}

Eigen::Vector3d logSO3(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

namespace {
// Left Jacobian of SO(3) and its inverse.
Eigen::Matrix3d leftJacobian(const Eigen::Vector3d& omega) {
  const double theta = omega.norm();
  const Eigen::Matrix3d W = skew(omega);
  if (theta < 1e-8) return Eigen::Matrix3d::Identity() + 0.5 * W;
  const double t2 = theta * theta;
  return Eigen::Matrix3d::Identity() + (1 - std::cos(theta)) / t2 * W + (theta - std::sin(theta)) / (t2 * theta) * W * W;
}
}  // namespace

Eigen::Isometry3d levelOpticalInZUp() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() << 0, 0, 1, -1, 0, 0, 0, -1, 0;  // columns: optical x, y, z in the z-up frame
  return T;
}

Eigen::Isometry3d mountedOptical(const Eigen::Vector3d& xyz_m, const Eigen::Vector3d& rpy_deg) {
  const Eigen::Vector3d r = rpy_deg * (M_PI / 180.0);
  Eigen::Isometry3d T_base_body = Eigen::Isometry3d::Identity();
  T_base_body.linear() =
      (Eigen::AngleAxisd(r.z(), Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(r.y(), Eigen::Vector3d::UnitY()) *
       Eigen::AngleAxisd(r.x(), Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  T_base_body.translation() = xyz_m;
  return T_base_body * levelOpticalInZUp();
}

Eigen::Isometry3d expSE3(const Vector6d& xi) {
  const Eigen::Vector3d omega = xi.head<3>();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = expSO3(omega);
  T.translation() = leftJacobian(omega) * xi.tail<3>();
  return T;
}

Vector6d logSE3(const Eigen::Isometry3d& T) {
  Vector6d xi;
  const Eigen::Vector3d omega = logSO3(T.linear());
  xi.head<3>() = omega;
  xi.tail<3>() = leftJacobian(omega).inverse() * T.translation();
  return xi;
}

double rotationAngle(const Eigen::Isometry3d& T) {
  const double c = std::clamp((T.linear().trace() - 1.0) * 0.5, -1.0, 1.0);
  return std::acos(c);
}

double translationNorm(const Eigen::Isometry3d& T) { return T.translation().norm(); }

bool isRigid(const Eigen::Matrix4d& T, double tolerance) {
  if (!T.allFinite()) return false;
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > tolerance) return false;
  if (std::abs(R.determinant() - 1.0) > tolerance) return false;
  const Eigen::RowVector4d bottom = T.row(3);
  return (bottom - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() <= tolerance;
}

Eigen::Isometry3d interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double t) {
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = qa.slerp(t, qb).toRotationMatrix();
  T.translation() = (1 - t) * a.translation() + t * b.translation();
  return T;
}

}  // namespace hxmap::alg
