// The analytic scene the fusion and photo-depth tests share: a small camera
// on a ring of radius 0.3 m about a point (axis y), looking at it.
#pragma once

#include <cmath>
#include <numbers>

#include <Eigen/Geometry>

#include "core/camera_model.h"

namespace s2r::ring_scene {

constexpr double kDeg = std::numbers::pi / 180;
inline const Eigen::Vector3d kCentre(0.01, -0.02, 0.03);
constexpr double kRadius = 0.05;  // the sphere the tests draw about kCentre

inline Intrinsics camera() {
  Intrinsics K;
  K.width = 160, K.height = 120, K.fx = K.fy = 150, K.cx = 79.5, K.cy = 59.5;
  return K;
}

// Elevation above the ring's plane towards -y.
inline Eigen::Isometry3d ring_pose(double angle_deg, double elevation_deg = 10) {
  const double a = angle_deg * kDeg, e = elevation_deg * kDeg;
  const Eigen::Vector3d eye = kCentre + 0.3 * Eigen::Vector3d(std::sin(a) * std::cos(e), -std::sin(e), -std::cos(a) * std::cos(e));
  const Eigen::Vector3d z = (kCentre - eye).normalized();
  const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() << x, z.cross(x), z;
  T.translation() = eye;
  return T;
}

}  // namespace s2r::ring_scene
