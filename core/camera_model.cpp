#include "core/camera_model.h"

#include <cmath>

namespace s2r {

bool Intrinsics::has_distortion() const {
  for (double d : dist)
    if (d != 0.0) return true;
  return false;
}

std::optional<Eigen::Vector2d> Intrinsics::undistort(const Eigen::Vector2d& xd) const { return undistort(xd, xd); }

std::optional<Eigen::Vector2d> Intrinsics::undistort(const Eigen::Vector2d& xd, const Eigen::Vector2d& start) const {
  if (!has_distortion()) return xd;
  Eigen::Vector2d x = start.allFinite() ? start : xd;
  const double k1 = dist[0], k2 = dist[1], p1 = dist[2], p2 = dist[3], k3 = dist[4];
  for (int it = 0; it < 20; ++it) {
    const double u = x.x(), v = x.y();
    const double r2 = u * u + v * v;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2);  // d radial / d r2
    Eigen::Vector2d f = distort(x) - xd;
    Eigen::Matrix2d J;
    J(0, 0) = radial + u * dradial * 2 * u + 2 * p1 * v + p2 * 6 * u;
    J(0, 1) = u * dradial * 2 * v + 2 * p1 * u + p2 * 2 * v;
    J(1, 0) = v * dradial * 2 * u + p1 * 2 * u + 2 * p2 * v;
    J(1, 1) = radial + v * dradial * 2 * v + p1 * 6 * v + 2 * p2 * u;
    const double det = J.determinant();
    if (!std::isfinite(det) || std::abs(det) < 1e-12) return std::nullopt;
    Eigen::Vector2d step = J.inverse() * f;
    x -= step;
    if (step.squaredNorm() < 1e-24) break;
  }
  if (!x.allFinite() || (distort(x) - xd).norm() > 1e-9) return std::nullopt;
  return x;
}

std::optional<Eigen::Vector3d> Intrinsics::ray(const Eigen::Vector2d& pixel) const {
  auto xn = undistort({(pixel.x() - cx) / fx, (pixel.y() - cy) / fy});
  if (!xn) return std::nullopt;
  return Eigen::Vector3d(xn->x(), xn->y(), 1.0);
}

std::optional<Eigen::Vector3d> Intrinsics::unproject(const Eigen::Vector2d& pixel,
                                                     double z) const {
  auto r = ray(pixel);
  if (!r) return std::nullopt;
  return *r * z;
}

Eigen::Matrix3d Intrinsics::K() const {
  Eigen::Matrix3d k;
  k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
  return k;
}

Status Intrinsics::validate(const std::string& where) const {
  auto bad = [&](const std::string& field, const std::string& why) {
    return fail(where + "." + field + ": " + why);
  };
  if (width <= 0 || height <= 0) return bad("width/height", "image size must be positive");
  const std::pair<const char*, double> named[] = {{"fx", fx}, {"fy", fy}, {"cx", cx}, {"cy", cy}};
  for (auto [name, v] : named)
    if (!std::isfinite(v)) return bad(name, "not a finite number");
  if (!(fx > 0)) return bad("fx", "focal length must be > 0");
  if (!(fy > 0)) return bad("fy", "focal length must be > 0");
  for (size_t i = 0; i < dist.size(); ++i)
    if (!std::isfinite(dist[i])) return bad("dist[" + std::to_string(i) + "]", "not a finite number");
  return {};
}

Eigen::Isometry3d rotation_about_axis(const Eigen::Vector3d& axis_dir,
                                      const Eigen::Vector3d& axis_point, double angle_rad) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::AngleAxisd(angle_rad, axis_dir.normalized()).toRotationMatrix();
  t.translation() = axis_point - t.linear() * axis_point;
  return t;
}

}  // namespace s2r
