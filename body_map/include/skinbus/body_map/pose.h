// skinbus/body_map/pose.h: rigid transforms in millimetres, and the rotation conventions of the
// body map (URDF roll-pitch-yaw, quaternions, rotation vectors).
//
// A `Pose` maps points of a child frame into its parent frame:
//   p_parent = rotation * p_child + translation_mm.
// Every length in body_map is in millimetres (URDF metres are converted when a model is loaded);
// every angle is in radians unless its name says `_deg`.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace skinbus::body_map {

struct Pose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation_mm = Eigen::Vector3d::Zero();

  // The point `p_mm` of the child frame, in the parent frame.
  Eigen::Vector3d apply(const Eigen::Vector3d& p_mm) const {
    return rotation * p_mm + translation_mm;
  }
  // Composition: (a * b).apply(p) == a.apply(b.apply(p)).
  Pose operator*(const Pose& b) const {
    return {rotation * b.rotation, rotation * b.translation_mm + translation_mm};
  }
  Pose inverse() const {
    const Eigen::Matrix3d rt = rotation.transpose();
    return {rt, -(rt * translation_mm)};
  }
};

// URDF's fixed-axis roll, pitch, yaw (radians): R = Rz(yaw) * Ry(pitch) * Rx(roll).
inline Eigen::Matrix3d rotation_from_rpy(double roll, double pitch, double yaw) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

// The inverse of rotation_from_rpy: roll, pitch, yaw in radians (pitch in [-pi/2, pi/2]).
inline Eigen::Vector3d rpy_from_rotation(const Eigen::Matrix3d& r) {
  const double pitch = std::atan2(-r(2, 0), std::hypot(r(0, 0), r(1, 0)));
  const double roll = std::atan2(r(2, 1), r(2, 2));
  const double yaw = std::atan2(r(1, 0), r(0, 0));
  return {roll, pitch, yaw};
}

// Rotation by axis * angle (radians); the zero vector is the identity.
inline Eigen::Matrix3d rotation_from_vector(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

// The angle (radians, 0..pi) of the rotation that takes `a` to `b`; accurate for tiny angles too
// (atan2 of the rotation's sine and cosine parts, not acos of the trace alone).
inline double rotation_angle_between(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const Eigen::Matrix3d r = a.transpose() * b;
  const Eigen::Vector3d s(r(2, 1) - r(1, 2), r(0, 2) - r(2, 0), r(1, 0) - r(0, 1));
  return std::atan2(0.5 * s.norm(), 0.5 * (r.trace() - 1.0));
}

}  // namespace skinbus::body_map
