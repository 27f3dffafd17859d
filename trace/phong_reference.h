// The exact Phong lobe of an environment panorama (Okumura
// 2003): the brute-force reference a multi-scale environment map is measured
// against, and what the ray tracer returns for a glossy reflection.
//
//   I(r, L) = sum_w P(w) max(0, r.w)^L dOmega(w) / sum_w max(0, r.w)^L dOmega(w)
//
// over every pixel w of an equirectangular panorama, dOmega its solid angle.
// The lobe is normalised: L = 0 gives the mean of the hemisphere around r, and
// as L grows it tends to the panorama's value at r. Stable at any exponent:
// (r.w)^L = exp(L log(r.w)) with log(r.w) = log1p(-|r - w|^2 / 2), free of
// cancellation where r.w is near 1, and the weights are shifted by the largest
// log-weight before exponentiating, so L = 1e9 does not turn into 0/0.
//
// Panorama convention: pixel (x, y) of a W x H image looks along
//   longitude phi = 2 pi (x + 0.5) / W - pi,  latitude theta = pi/2 - pi (y + 0.5) / H,
//   direction (cos theta sin phi, sin theta, -cos theta cos phi)
// (y up; the image centre looks along -z); its solid angle is
// cos(theta) (2 pi / W) (pi / H).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/result.h"

namespace s2r {

// The direction of pixel (x, y) of a W x H equirectangular image (convention above).
Eigen::Vector3d equirect_direction(int x, int y, int width, int height);

class Panorama {
 public:
  // Linear RGB (3 channels, or 1 read as grey), at least 4 x 2. Non-finite or
  // negative pixels are rejected, naming the first one.
  static Result<Panorama> create(ImageF rgb);

  int width() const { return rgb_.width; }
  int height() const { return rgb_.height; }
  Eigen::Vector3d direction(int x, int y) const;
  double solid_angle(int y) const;
  Eigen::Vector3f at(int x, int y) const;
  Eigen::Vector3f lookup(const Eigen::Vector3d& dir) const;  // nearest pixel
  // Every pixel's unit direction, precomputed (x fastest).
  const Eigen::Vector3d& unit(int x, int y) const { return dirs_[static_cast<size_t>(y) * rgb_.width + x]; }
  const ImageF& rgb() const { return rgb_; }

 private:
  ImageF rgb_;
  std::vector<Eigen::Vector3d> dirs_;
};

// Brute force over every pixel; `r` any non-zero finite direction,
// `exponent` >= 0 and finite.
Result<Eigen::Vector3d> phong_lobe(const Panorama& panorama, const Eigen::Vector3d& r, double exponent);

// The multi-scale environment map's exponent law (render/envmap.h):
// L = g(|t|) = 2 log I / log1p((2 / (|t| s))^2) for a map of s voxels per side
// and I intensity levels.
// g(|t|) above; radius in [0, 1] (larger radii are clamped to 1), size >= 2,
// levels > 1.
double envmap_exponent(double radius, int size, double intensity_levels);
// Its inverse: the radius whose lobe has this exponent (0 for L = 0, 1 for
// every L at or beyond g(1)).
double envmap_radius(double exponent, int size, double intensity_levels);

// The material's roughness in [0, 1] as a Phong exponent, independent of any
// map's resolution: the exponent a 128^3, 256-level map has at lambda = 1 -
// roughness (about 45,400 at roughness 0, 0 at roughness 1). A map of another
// size looks it up at envmap_radius(exponent).
double roughness_to_exponent(double roughness);

}  // namespace s2r
