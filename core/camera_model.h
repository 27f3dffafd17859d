// Pinhole camera with Brown-Conrady distortion (OpenCV's k1 k2 p1 p2 k3).
//
// Frames are named in transforms: `camera_from_world` maps world points into
// the camera; `world_from_camera` is the camera's pose. Camera frame: x right,
// y down, z forward (OpenCV convention). Pixel centres are at integer
// coordinates (OpenCV convention): pixel (0,0) covers [-0.5, 0.5]^2.
#pragma once

#include <array>
#include <cmath>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/result.h"

namespace s2r {

struct Intrinsics {
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::array<double, 5> dist{};  // k1 k2 p1 p2 k3

  bool has_distortion() const;
  // Normalised (x/z, y/z) -> distorted normalised coordinates.
  Eigen::Vector2d distort(const Eigen::Vector2d& xn) const;
  // Inverse of distort() by Newton iterations; nullopt where it does not
  // converge (far outside the calibrated field).
  std::optional<Eigen::Vector2d> undistort(const Eigen::Vector2d& xd) const;
  // The same, Newton's iterations started from `start` (a neighbouring
  // pixel's answer: fewer iterations to the same point).
  std::optional<Eigen::Vector2d> undistort(const Eigen::Vector2d& xd, const Eigen::Vector2d& start) const;

  // Camera-frame point -> pixel. nullopt behind the camera (z <= 0).
  std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& p_camera) const;
  // Pixel -> ray direction in the camera frame with z = 1.
  std::optional<Eigen::Vector3d> ray(const Eigen::Vector2d& pixel) const;
  // Pixel + depth along z -> camera-frame point.
  std::optional<Eigen::Vector3d> unproject(const Eigen::Vector2d& pixel, double z) const;

  bool contains(const Eigen::Vector2d& pixel) const {
    return pixel.x() >= -0.5 && pixel.y() >= -0.5 && pixel.x() < width - 0.5 &&
           pixel.y() < height - 0.5;
  }
  Eigen::Matrix3d K() const;

  // Sizes > 0, focal lengths > 0 and finite, principal point finite,
  // distortion finite. `where` prefixes the message.
  Status validate(const std::string& where) const;
};

// Rotation about a unit axis through a point: the turntable's motion.
Eigen::Isometry3d rotation_about_axis(const Eigen::Vector3d& axis_dir,
                                      const Eigen::Vector3d& axis_point, double angle_rad);

// The angle between two directions of any length, in [0, pi]: atan2 of |a x b|
// and a . b, exact near 0 and pi where acos of the normalised dot loses it.
inline double angle_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

}  // namespace s2r
