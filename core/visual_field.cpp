#include "core/visual_field.h"

#include <cmath>

#include <Eigen/Geometry>

namespace s2r {
namespace {

constexpr float kPiF = 3.14159265358979f;

// atan(t) for t >= 0 (+inf allowed): Cephes' atanf, range reduction to
// |x| <= tan(pi/8) and an odd degree-9 polynomial; about 1e-7 relative.
// glibc's atan2 costs ~45 ns here, and the tracer asks twice per pixel.
float atan_pos(float t) {
  float y = 0, x = t;
  if (t > 2.414213562373095f) {
    y = kPiF / 2;
    x = -1 / t;
  } else if (t > 0.4142135623730950f) {
    y = kPiF / 4;
    x = (t - 1) / (t + 1);
  }
  const float z = x * x;
  return y + (((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z - 3.33329491539e-1f) * z * x + x;
}

// atan2(y, x) for y >= 0, in [0, pi]; both zero gives 0 (the sign of a zero
// x is ignored).
float atan2_pos(float y, float x) {
  if (x == 0) return y == 0 ? 0.0f : kPiF / 2;
  return x > 0 ? atan_pos(y / x) : kPiF - atan_pos(y / -x);
}

}  // namespace

Result<EyeFrame> EyeFrame::look(const Eigen::Vector3d& gaze, const Eigen::Vector3d& world_up,
                                const Eigen::Vector3d& fallback_up) {
  if (!gaze.allFinite() || gaze.norm() == 0) return fail("gaze direction must be finite and non-zero");
  if (!world_up.allFinite() || world_up.norm() == 0 || !fallback_up.allFinite() || fallback_up.norm() == 0)
    return fail("up direction must be finite and non-zero");
  EyeFrame e;
  e.forward = gaze.normalized();
  Eigen::Vector3d right = e.forward.cross(world_up.normalized());
  // Within ~0.06 deg of the up axis the cross product loses its direction.
  if (right.norm() < 1e-3) right = e.forward.cross(fallback_up.normalized());
  if (right.norm() < 1e-3) return fail("gaze is parallel to both the up and the fallback up direction");
  e.right = right.normalized();
  e.up = e.right.cross(e.forward);
  return e;
}

namespace {

// cos(pi / (6 sqrt 2)) and tan(pi - 5pi/9) = tan(4pi/9), each rounded to the safe side.
constexpr float kCosInner = 0.93224045f, kTanBehind = 5.6712f;
constexpr float kCentralF = static_cast<float>(kCentralField), kTemporalF = static_cast<float>(kTemporalField);
constexpr float kUpperF = static_cast<float>(kUpperField), kLowerF = static_cast<float>(kLowerField);

bool in_inner_cone(const Eigen::Vector3f& d, float n2) { return d.x() > 0 && d.x() * d.x() >= kCosInner * kCosInner * n2; }
bool in_behind_cone(const Eigen::Vector3f& d) { return d.x() < 0 && std::abs(d.y()) <= -d.x() * kTanBehind; }

// Eq. 4-8 in single precision (a ray tracer asks once per pixel; the angles
// need no more than ~1e-7 rad). `d` is finite, non-zero and within float range.
FieldPoint field_core(const Eigen::Vector3f& d) {
  FieldPoint p;
  const float df = d.x(), dr = d.y(), du = d.z();
  const float ma = atan2_pos(std::abs(dr), df);            // eq. 4
  const float mb = atan2_pos(std::abs(du), std::abs(df));  // eq. 5, |m_b|
  const float l2 = ma * ma + mb * mb;
  const float l = std::sqrt(l2);                            // eq. 6
  p.m_a = ma;
  p.m_b = du < 0 ? -mb : mb;
  p.l = l;
  if (l <= kCentralF) {
    p.level = 1;
    return p;
  }
  const float b = du >= 0 ? kUpperF : kLowerF;
  const float edge = std::sqrt((kTemporalF * kTemporalF * ma * ma + b * b * mb * mb) / l2);  // eq. 7
  p.edge = edge;
  p.level = l < edge ? (edge - l) / (edge - kCentralF) : 0.0f;  // eq. 8
  return p;
}

}  // namespace

FieldPoint visual_field(const Eigen::Vector3d& d) {
  if (!d.allFinite() || d.squaredNorm() == 0) return {};
  // Scaled so that any finite double length stays in float range.
  const double big = d.cwiseAbs().maxCoeff();
  return field_core((big > 1e-30 && big < 1e30 ? d : Eigen::Vector3d(d / big)).cast<float>());
}

float field_level(const Eigen::Vector3f& d) {
  const float n2 = d.squaredNorm();
  if (!(n2 > 0) || !std::isfinite(n2)) return visual_field(d.cast<double>()).level;
  if (in_inner_cone(d, n2)) return 1.0f;
  if (in_behind_cone(d)) return 0.0f;
  return static_cast<float>(field_core(d).level);
}

double field_level(const Eigen::Vector3d& d) {
  const double big = d.cwiseAbs().maxCoeff();
  if (!d.allFinite() || big == 0) return 0.0;
  const Eigen::Vector3f f = (big > 1e-30 && big < 1e30 ? d : Eigen::Vector3d(d / big)).cast<float>();
  return field_level(f);
}

FieldRegion field_region(const EyeFrame& eye, const Eigen::Vector3d (&corner_dirs)[4]) {
  bool inner = true, behind = true;
  for (const auto& w : corner_dirs) {
    const Eigen::Vector3d d = eye.to_eye(w);
    const double n2 = d.squaredNorm();
    if (!(n2 > 0) || !std::isfinite(n2)) return FieldRegion::kMixed;
    const Eigen::Vector3f f = (d / std::sqrt(n2)).cast<float>();
    inner = inner && in_inner_cone(f, f.squaredNorm());
    behind = behind && in_behind_cone(f);
  }
  return inner ? FieldRegion::kCentral : behind ? FieldRegion::kOutside : FieldRegion::kMixed;
}

}  // namespace s2r
