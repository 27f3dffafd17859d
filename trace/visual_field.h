// Visual-field level of detail (Mochizuki and Makino; docs/references.md): how much
// detail a ray gets from where it lies in the viewer's field of view.
//
// A direction D' is taken into the eye frame (E_f gaze, E_r right, E_u up):
// d_f = E_f.D', d_r = E_r.D', d_u = E_u.D' (eq. 1-3). Then
//   m_a = acos(d_f / sqrt(d_f^2 + d_r^2))                       (eq. 4)
//   m_b = +-acos|d_f / sqrt(d_f^2 + d_u^2)|, sign of d_u          (eq. 5)
//   l   = sqrt(m_a^2 + m_b^2)                                     (eq. 6)
//   L   = sqrt(((5pi/9)^2 m_a^2 + B^2 m_b^2) / (m_a^2 + m_b^2)),  (eq. 7)
//         B = pi/3 above the gaze, 7pi/18 below
//   level = 1 (l <= pi/6), (L - l)/(L - pi/6) (pi/6 < l <= L), 0 (L < l)  (eq. 8)
//
// Computed without the formula's singular spots: acos(a / sqrt(a^2 + b^2))
// is atan2(|b|, a), equal for every (a, b) with a^2 + b^2 > 0, defined (0) at
// a = b = 0 (straight up, down or sideways), and free of the acos argument
// drifting past +-1 by rounding. L is needed only in the periphery, where l
// > pi/6 > 0, so its 0/0 at the gaze never arises.
#pragma once

#include <Eigen/Core>

#include "core/result.h"

namespace s2r {

inline constexpr double kCentralField = 0.5235987755982988;   // pi/6
inline constexpr double kTemporalField = 1.7453292519943295;  // 5pi/9, left and right
inline constexpr double kUpperField = 1.0471975511965976;     // pi/3
inline constexpr double kLowerField = 1.2217304763960306;     // 7pi/18

struct EyeFrame {
  Eigen::Vector3d forward = -Eigen::Vector3d::UnitZ();  // E_f
  Eigen::Vector3d right = Eigen::Vector3d::UnitX();     // E_r
  Eigen::Vector3d up = Eigen::Vector3d::UnitY();        // E_u

  // From a gaze direction and the world's up. A gaze along up (looking
  // straight down or up) takes `fallback_up` (default: -z, "the top of the
  // head points forward") instead; both must be finite and non-zero.
  static Result<EyeFrame> look(const Eigen::Vector3d& gaze, const Eigen::Vector3d& world_up = Eigen::Vector3d::UnitY(),
                               const Eigen::Vector3d& fallback_up = -Eigen::Vector3d::UnitZ());
  Eigen::Vector3d to_eye(const Eigen::Vector3d& world_dir) const {
    return {forward.dot(world_dir), right.dot(world_dir), up.dot(world_dir)};
  }
};

struct FieldPoint {
  double m_a = 0, m_b = 0;  // radians: m_a in [0, pi], m_b in [-pi/2, pi/2]
  double l = 0;             // distance from the gaze in the (m_a, m_b) plane
  double edge = 0;          // L: the field's edge along that line (0 when l <= pi/6)
  double level = 0;         // 1 central, (0, 1) periphery, 0 outside
};

// `d_eye` = (d_f, d_r, d_u), any length. A zero or non-finite vector is
// outside the field (level 0).
FieldPoint visual_field(const Eigen::Vector3d& d_eye);
// The level alone, the same value as visual_field(d_eye).level, with two
// shortcuts that skip the arctangents: within pi/(6 sqrt 2) of the gaze the
// level is 1 (m_a and |m_b| never exceed the angle to the gaze there, so
// l <= sqrt 2 times it <= pi/6); behind the eye with m_a >= 5pi/9 it is 0
// (l >= m_a >= 5pi/9 >= L).
double field_level(const Eigen::Vector3d& d_eye);
float field_level(const Eigen::Vector3f& d_eye);  // the same, for a tracer's float rays
// field_level of kFieldBatch directions at once, (d_f, d_r, d_u) as three
// arrays: the same bits lane for lane, in SIMD (a row of a tracer's tile).
inline constexpr int kFieldBatch = 16;
void field_levels(const float* d_f, const float* d_r, const float* d_u, float* level);
inline double field_level(const EyeFrame& eye, const Eigen::Vector3d& world_dir) {
  return field_level(eye.to_eye(world_dir));
}

// Both shortcut regions are convex cones, and the rays through a flat
// rectangle of pixels are the cone spanned by its corner rays; so when all
// four corners lie in one region, every pixel between them does. A tracer
// then sets a whole tile's level without asking per pixel.
enum class FieldRegion { kCentral, kOutside, kMixed };
FieldRegion field_region(const EyeFrame& eye, const Eigen::Vector3d (&corner_dirs)[4]);

}  // namespace s2r
