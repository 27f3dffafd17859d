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
  // Normalised (x/z, y/z) -> distorted normalised coordinates. (Inline, as
  // project: both run per facet and camera in reconstruct.)
  Eigen::Vector2d distort(const Eigen::Vector2d& xn) const {
    const double x = xn.x(), y = xn.y();
    const double r2 = x * x + y * y;
    const double k1 = dist[0], k2 = dist[1], p1 = dist[2], p2 = dist[3], k3 = dist[4];
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    return {x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y};
  }
  // Inverse of distort() by Newton iterations; nullopt where it does not
  // converge (far outside the calibrated field).
  std::optional<Eigen::Vector2d> undistort(const Eigen::Vector2d& xd) const;
  // The same, Newton's iterations started from `start` (a neighbouring
  // pixel's answer: fewer iterations to the same point).
  std::optional<Eigen::Vector2d> undistort(const Eigen::Vector2d& xd, const Eigen::Vector2d& start) const;

  // Camera-frame point -> pixel. nullopt behind the camera (z <= 0).
  std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& p) const {
    if (!(p.z() > 0)) return std::nullopt;
    const Eigen::Vector2d d = distort({p.x() / p.z(), p.y() / p.z()});
    return Eigen::Vector2d(fx * d.x() + cx, fy * d.y() + cy);
  }
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

// std::lround (halves away from zero) without the library call, for
// |v| < 2^31: the truncation and the remainder v - t are exact there.
inline int round_half_away(double v) {
  const int t = int(v);
  const double f = v - double(t);
  return t + int(f >= 0.5) - int(f <= -0.5);
}

// Rotation about a unit axis through a point: the turntable's motion.
Eigen::Isometry3d rotation_about_axis(const Eigen::Vector3d& axis_dir,
                                      const Eigen::Vector3d& axis_point, double angle_rad);

// The angle between two directions of any length, in [0, pi]: atan2 of |a x b|
// and a . b, exact near 0 and pi where acos of the normalised dot loses it.
inline double angle_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

}  // namespace s2r
