#include "trace/visual_field.h"

#include <cmath>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <Eigen/Geometry>

namespace s2r {
namespace {

constexpr float kPiF = 3.14159265358979f;

// Every formula below is written once, over Eigen arrays of N floats: N = 1
// serves single directions, N = kFieldBatch a row of pixels in SIMD (Eigen's
// packets; selects instead of branches). The operations are the same IEEE
// single-precision ones in the same order, so both give the same bits.
template <int N>
using Lanes = Eigen::Array<float, N, 1>;

// Correctly rounded square roots in every lane: Eigen's packet sqrt may take
// the fast reciprocal-estimate path (EIGEN_FAST_MATH), a bit away from
// std::sqrt.
template <int N>
Lanes<N> exact_sqrt(const Lanes<N>& x) {
  return x.unaryExpr([](float v) { return std::sqrt(v); });
}

// atan(t) for t >= 0 (+inf allowed): Cephes' atanf, range reduction to
// |x| <= tan(pi/8) and an odd degree-9 polynomial; about 1e-7 relative.
// glibc's atan2 costs ~45 ns here, and the tracer asks twice per pixel.
template <int N>
Lanes<N> atan_pos(const Lanes<N>& t) {
  const Eigen::Array<bool, N, 1> big = t > 2.414213562373095f;
  const Eigen::Array<bool, N, 1> mid = t > 0.4142135623730950f;
  const Lanes<N> x = big.select(-1 / t, mid.select((t - 1) / (t + 1), t));
  const Lanes<N> y = big.select(Lanes<N>::Constant(kPiF / 2), mid.select(Lanes<N>::Constant(kPiF / 4), Lanes<N>::Zero()));
  const Lanes<N> z = x * x;
  return y + (((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z - 3.33329491539e-1f) * z * x + x;
}

// atan2(y, x) for y >= 0, in [0, pi]; both zero gives 0 (the sign of a zero
// x is ignored).
template <int N>
Lanes<N> atan2_pos(const Lanes<N>& y, const Lanes<N>& x) {
  const Lanes<N> a = atan_pos<N>(y / x.abs());  // inf or NaN where x = 0: selected away
  const Lanes<N> r = (x > 0).select(a, kPiF - a);
  return (x == 0).select((y == 0).select(Lanes<N>::Zero(), Lanes<N>::Constant(kPiF / 2)), r);
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
// need no more than ~1e-7 rad). Every lane finite, non-zero and within float
// range. Fills m_a, |m_b|, l and L (L only meaningful where l > pi/6).
template <int N>
struct FieldLanes {
  Lanes<N> ma, mb, l, edge, level;
};

template <int N>
FieldLanes<N> field_lanes(const Lanes<N>& df, const Lanes<N>& dr, const Lanes<N>& du) {
  FieldLanes<N> p;
  p.ma = atan2_pos<N>(dr.abs(), df);         // eq. 4
  p.mb = atan2_pos<N>(du.abs(), df.abs());   // eq. 5, |m_b|
  const Lanes<N> l2 = p.ma * p.ma + p.mb * p.mb;
  p.l = exact_sqrt<N>(l2);                           // eq. 6
  const Lanes<N> b = (du >= 0).select(Lanes<N>::Constant(kUpperF), Lanes<N>::Constant(kLowerF));
  // eq. 7 (0/0 at the gaze, where l2 = 0: that lane is central and takes level 1 below)
  p.edge = exact_sqrt<N>((kTemporalF * kTemporalF * p.ma * p.ma + b * b * p.mb * p.mb) / l2);
  p.level = (p.l <= kCentralF).select(Lanes<N>::Ones(),                                           // eq. 8
                                      (p.l < p.edge).select((p.edge - p.l) / (p.edge - kCentralF), Lanes<N>::Zero()));
  return p;
}

// The level with the two shortcut cones (visual_field.h), per lane.
template <int N>
Lanes<N> level_lanes(const Lanes<N>& df, const Lanes<N>& dr, const Lanes<N>& du) {
  const Lanes<N> n2 = df * df + dr * dr + du * du;
  const Eigen::Array<bool, N, 1> inner = (df > 0) && (df * df >= kCosInner * kCosInner * n2);
  const Eigen::Array<bool, N, 1> behind = (df < 0) && (dr.abs() <= -df * kTanBehind);
  return inner.select(Lanes<N>::Ones(), behind.select(Lanes<N>::Zero(), field_lanes<N>(df, dr, du).level));
}

FieldPoint field_core(const Eigen::Vector3f& d) {
  const FieldLanes<1> f = field_lanes<1>(Lanes<1>(d.x()), Lanes<1>(d.y()), Lanes<1>(d.z()));
  FieldPoint p;
  p.m_a = f.ma(0);
  p.m_b = d.z() < 0 ? -f.mb(0) : f.mb(0);
  p.l = f.l(0);
  p.edge = f.l(0) <= kCentralF ? 0.0f : f.edge(0);
  p.level = f.level(0);
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
  return level_lanes<1>(Lanes<1>(d.x()), Lanes<1>(d.y()), Lanes<1>(d.z()))(0);
}

#if defined(__SSE2__)
namespace {

// level_lanes<1> four lanes at a time with SSE2: the same IEEE operations in
// the same order (x86-64 does scalar float in SSE too), selects as masks.
struct Sse {
  static __m128 sel(__m128 m, __m128 a, __m128 b) { return _mm_or_ps(_mm_and_ps(m, a), _mm_andnot_ps(m, b)); }
  static __m128 abs(__m128 x) { return _mm_andnot_ps(_mm_set1_ps(-0.0f), x); }
  static __m128 c(float v) { return _mm_set1_ps(v); }

  static __m128 atan_pos(__m128 t) {
    const __m128 big = _mm_cmpgt_ps(t, c(2.414213562373095f)), mid = _mm_cmpgt_ps(t, c(0.4142135623730950f));
    const __m128 x = sel(big, _mm_div_ps(c(-1.0f), t), sel(mid, _mm_div_ps(_mm_sub_ps(t, c(1)), _mm_add_ps(t, c(1))), t));
    const __m128 y = sel(big, c(kPiF / 2), sel(mid, c(kPiF / 4), _mm_setzero_ps()));
    const __m128 z = _mm_mul_ps(x, x);
    __m128 q = _mm_sub_ps(_mm_mul_ps(c(8.05374449538e-2f), z), c(1.38776856032e-1f));
    q = _mm_add_ps(_mm_mul_ps(q, z), c(1.99777106478e-1f));
    q = _mm_sub_ps(_mm_mul_ps(q, z), c(3.33329491539e-1f));
    q = _mm_mul_ps(_mm_mul_ps(q, z), x);
    return _mm_add_ps(_mm_add_ps(y, q), x);
  }

  static __m128 atan2_pos(__m128 y, __m128 x) {
    const __m128 a = atan_pos(_mm_div_ps(y, abs(x)));
    const __m128 r = sel(_mm_cmpgt_ps(x, _mm_setzero_ps()), a, _mm_sub_ps(c(kPiF), a));
    const __m128 axis = sel(_mm_cmpeq_ps(y, _mm_setzero_ps()), _mm_setzero_ps(), c(kPiF / 2));
    return sel(_mm_cmpeq_ps(x, _mm_setzero_ps()), axis, r);
  }

  static __m128 level(__m128 df, __m128 dr, __m128 du) {
    const __m128 ma = atan2_pos(abs(dr), df), mb = atan2_pos(abs(du), abs(df));
    const __m128 l2 = _mm_add_ps(_mm_mul_ps(ma, ma), _mm_mul_ps(mb, mb));
    const __m128 l = _mm_sqrt_ps(l2);
    const __m128 b = sel(_mm_cmpge_ps(du, _mm_setzero_ps()), c(kUpperF), c(kLowerF));
    const __m128 num = _mm_add_ps(_mm_mul_ps(_mm_mul_ps(c(kTemporalF * kTemporalF), ma), ma),
                                  _mm_mul_ps(_mm_mul_ps(_mm_mul_ps(b, b), mb), mb));
    const __m128 edge = _mm_sqrt_ps(_mm_div_ps(num, l2));
    const __m128 outer = sel(_mm_cmplt_ps(l, edge), _mm_div_ps(_mm_sub_ps(edge, l), _mm_sub_ps(edge, c(kCentralF))),
                             _mm_setzero_ps());
    const __m128 lv = sel(_mm_cmple_ps(l, c(kCentralF)), c(1), outer);
    const __m128 n2 = _mm_add_ps(_mm_add_ps(_mm_mul_ps(df, df), _mm_mul_ps(dr, dr)), _mm_mul_ps(du, du));
    const __m128 inner = _mm_and_ps(_mm_cmpgt_ps(df, _mm_setzero_ps()),
                                    _mm_cmpge_ps(_mm_mul_ps(df, df), _mm_mul_ps(c(kCosInner * kCosInner), n2)));
    const __m128 behind = _mm_and_ps(_mm_cmplt_ps(df, _mm_setzero_ps()),
                                     _mm_cmple_ps(abs(dr), _mm_mul_ps(_mm_sub_ps(_mm_setzero_ps(), df), c(kTanBehind))));
    return sel(inner, c(1), sel(behind, _mm_setzero_ps(), lv));
  }
};

}  // namespace
#endif

void field_levels(const float* df, const float* dr, const float* du, float* level) {
  using B = Lanes<kFieldBatch>;
  const B f = Eigen::Map<const B>(df), r = Eigen::Map<const B>(dr), u = Eigen::Map<const B>(du);
  const B n2 = f * f + r * r + u * u;
  if (!((n2 > 0).all() && n2.isFinite().all())) {  // a zero or huge direction: one at a time
    for (int i = 0; i < kFieldBatch; ++i) level[i] = field_level(Eigen::Vector3f(df[i], dr[i], du[i]));
    return;
  }
#if defined(__SSE2__)
  static_assert(kFieldBatch % 4 == 0);
  for (int i = 0; i < kFieldBatch; i += 4)
    _mm_storeu_ps(level + i, Sse::level(_mm_loadu_ps(df + i), _mm_loadu_ps(dr + i), _mm_loadu_ps(du + i)));
#else
  Eigen::Map<B> out(level);
  out = level_lanes<kFieldBatch>(f, r, u);
#endif
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
