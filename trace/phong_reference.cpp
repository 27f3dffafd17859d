#include "trace/phong_reference.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <spdlog/fmt/fmt.h>

namespace s2r {

Result<Panorama> Panorama::create(ImageF rgb) {
  if (rgb.width < 4 || rgb.height < 2) return fail(fmt::format("panorama is {}x{}: at least 4x2 needed", rgb.width, rgb.height));
  if (rgb.channels != 3 && rgb.channels != 1) return fail(fmt::format("panorama has {} channels: 1 or 3 needed", rgb.channels));
  if (rgb.channels == 1) {
    ImageF c(rgb.width, rgb.height, 3);
    for (size_t i = 0; i < rgb.pixels(); ++i) c.data[3 * i] = c.data[3 * i + 1] = c.data[3 * i + 2] = rgb.data[i];
    rgb = std::move(c);
  }
  for (size_t i = 0; i < rgb.data.size(); ++i)
    if (!std::isfinite(rgb.data[i]) || rgb.data[i] < 0) {
      const size_t p = i / 3;
      return fail(fmt::format("panorama pixel ({}, {}) is {}: radiance must be finite and >= 0", p % rgb.width,
                              p / rgb.width, rgb.data[i]));
    }
  Panorama out;
  out.rgb_ = std::move(rgb);
  out.dirs_.resize(out.rgb_.pixels());
  for (int y = 0; y < out.rgb_.height; ++y)
    for (int x = 0; x < out.rgb_.width; ++x) out.dirs_[static_cast<size_t>(y) * out.rgb_.width + x] = out.direction(x, y);
  return out;
}

Eigen::Vector3d equirect_direction(int x, int y, int width, int height) {
  const double phi = 2 * M_PI * (x + 0.5) / width - M_PI;
  const double theta = M_PI / 2 - M_PI * (y + 0.5) / height;
  return {std::cos(theta) * std::sin(phi), std::sin(theta), -std::cos(theta) * std::cos(phi)};
}

Eigen::Vector3d Panorama::direction(int x, int y) const { return equirect_direction(x, y, rgb_.width, rgb_.height); }

double Panorama::solid_angle(int y) const {
  const double theta = M_PI / 2 - M_PI * (y + 0.5) / rgb_.height;
  return std::cos(theta) * (2 * M_PI / rgb_.width) * (M_PI / rgb_.height);
}

Eigen::Vector3f Panorama::at(int x, int y) const { return {rgb_.at(x, y, 0), rgb_.at(x, y, 1), rgb_.at(x, y, 2)}; }

Eigen::Vector3f Panorama::lookup(const Eigen::Vector3d& d) const {
  const Eigen::Vector3d u = d.normalized();
  const double phi = std::atan2(u.x(), -u.z());
  const double theta = std::asin(std::clamp(u.y(), -1.0, 1.0));
  const int x = std::clamp(static_cast<int>(std::floor((phi + M_PI) / (2 * M_PI) * rgb_.width)), 0, rgb_.width - 1);
  const int y = std::clamp(static_cast<int>(std::floor((M_PI / 2 - theta) / M_PI * rgb_.height)), 0, rgb_.height - 1);
  return at(x, y);
}

Result<Eigen::Vector3d> phong_lobe(const Panorama& pano, const Eigen::Vector3d& r_in, double exponent) {
  if (!r_in.allFinite() || r_in.norm() == 0) return fail("Phong lobe: the reflection direction must be finite and non-zero");
  if (!std::isfinite(exponent) || exponent < 0) return fail(fmt::format("Phong lobe: exponent {} must be finite and >= 0", exponent));
  const Eigen::Vector3d r = r_in.normalized();
  // log weight of every pixel in the hemisphere: L log(r.w) + log dOmega.
  const int W = pano.width(), H = pano.height();
  std::vector<double> logw(static_cast<size_t>(W) * H, -std::numeric_limits<double>::infinity());
  double top = -std::numeric_limits<double>::infinity();
  for (int y = 0; y < H; ++y) {
    const double log_area = std::log(pano.solid_angle(y));
    for (int x = 0; x < W; ++x) {
      const Eigen::Vector3d w = pano.unit(x, y);
      const double c = r.dot(w);
      if (c <= 0) continue;
      // log cos from the chord: exact where cos is near 1 (1 - cos would cancel).
      const double log_cos = std::log1p(-0.5 * (r - w).squaredNorm());
      const double lw = (exponent == 0 ? 0.0 : exponent * log_cos) + log_area;
      logw[static_cast<size_t>(y) * W + x] = lw;
      top = std::max(top, lw);
    }
  }
  if (!std::isfinite(top)) return fail("Phong lobe: no panorama pixel in the hemisphere around the direction");
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double norm = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const double lw = logw[static_cast<size_t>(y) * W + x];
      if (!std::isfinite(lw)) continue;
      const double wgt = std::exp(lw - top);  // <= 1; the largest is exactly 1
      sum += wgt * pano.at(x, y).cast<double>();
      norm += wgt;
    }
  return Eigen::Vector3d(sum / norm);
}

double envmap_exponent(double radius, int size, double levels) {
  const double r = std::clamp(radius, 0.0, 1.0);
  if (r == 0) return 0;
  // x: tan of the angle between neighbouring voxels at this radius. g decays
  // only as 1 / log(1 / r): where x^2 would overflow, log1p(x^2) = 2 log x.
  const double log_x = std::log(2.0) - std::log(r) - std::log(static_cast<double>(size));
  if (log_x > 100) return std::log(levels) / log_x;
  const double x = std::exp(log_x);
  return 2 * std::log(levels) / std::log1p(x * x);
}

double envmap_radius(double exponent, int size, double levels) {
  if (!(exponent > 0)) return 0;
  if (exponent >= envmap_exponent(1, size, levels)) return 1;
  const double x2 = std::expm1(2 * std::log(levels) / exponent);  // (2 / (|t| s))^2
  if (!std::isfinite(x2)) return 0;
  return std::clamp(2 / (size * std::sqrt(x2)), 0.0, 1.0);
}

double roughness_to_exponent(double roughness) { return envmap_exponent(1 - std::clamp(roughness, 0.0, 1.0), 128, 256); }

}  // namespace s2r
