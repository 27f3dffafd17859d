// The registration's residuals as Ceres functors (templated for automatic
// differentiation; tests/registration_test checks them with GradientChecker).
// Internal to reconstruct/: includes Ceres.
#pragma once

#include <ceres/rotation.h>

#include <Eigen/Geometry>

namespace s2r::reg {

// Point-to-plane between view a's point p_a and view b's point q_b with normal
// n_b (each in its own sensor frame), poses as unit quaternion (Eigen order
// x y z w) + translation: ((R_a p_a + t_a) - (R_b q_b + t_b)) . (R_b n_b) / sigma.
struct FreePointToPlane {
  Eigen::Vector3d p_a, q_b, n_b;
  double inv_sigma = 1;

  template <typename T>
  bool operator()(const T* qa, const T* ta, const T* qb, const T* tb, T* r) const {
    const Eigen::Map<const Eigen::Quaternion<T>> Ra(qa), Rb(qb);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> Ta(ta), Tb(tb);
    const Eigen::Matrix<T, 3, 1> xa = Ra * p_a.cast<T>() + Ta;
    const Eigen::Matrix<T, 3, 1> xb = Rb * q_b.cast<T>() + Tb;
    const Eigen::Matrix<T, 3, 1> nb = Rb * n_b.cast<T>();
    r[0] = nb.dot(xa - xb) * T(inv_sigma);
    return true;
  }
};

// A turntable view's pose: its initial pose P0 (world_from_sensor), turned by
// `dtheta` about the axis (unit d through c), then tilted by tilt[0] e1 +
// tilt[1] e2 (e1, e2 perpendicular to d) about c and shifted by `shift`.
struct TurntableFrame {
  Eigen::Vector3d d, c, e1, e2;
};

template <typename T>
Eigen::Matrix<T, 3, 1> turntable_apply(const TurntableFrame& f, const T* dtheta, const T* tilt, const T* shift,
                                       const Eigen::Matrix<T, 3, 1>& y, bool direction) {
  // y is already in the world frame of the initial pose (P0 applied).
  const Eigen::Matrix<T, 3, 1> c = f.c.cast<T>();
  Eigen::Matrix<T, 3, 1> v = direction ? y : Eigen::Matrix<T, 3, 1>(y - c);
  const Eigen::Matrix<T, 3, 1> aa1 = f.d.cast<T>() * dtheta[0];
  Eigen::Matrix<T, 3, 1> w;
  ceres::AngleAxisRotatePoint(aa1.data(), v.data(), w.data());
  const Eigen::Matrix<T, 3, 1> aa2 = f.e1.cast<T>() * tilt[0] + f.e2.cast<T>() * tilt[1];
  ceres::AngleAxisRotatePoint(aa2.data(), w.data(), v.data());
  if (direction) return v;
  return v + c + Eigen::Map<const Eigen::Matrix<T, 3, 1>>(shift);
}

struct TurntablePointToPlane {
  TurntableFrame frame;
  Eigen::Vector3d p_a, q_b, n_b;  // already mapped by each view's initial pose (world frame)
  double inv_sigma = 1;

  template <typename T>
  bool operator()(const T* tha, const T* tia, const T* sha, const T* thb, const T* tib, const T* shb,
                  T* r) const {
    const auto xa = turntable_apply<T>(frame, tha, tia, sha, p_a.cast<T>(), false);
    const auto xb = turntable_apply<T>(frame, thb, tib, shb, q_b.cast<T>(), false);
    const auto nb = turntable_apply<T>(frame, thb, tib, shb, n_b.cast<T>(), true);
    r[0] = nb.dot(xa - xb) * T(inv_sigma);
    return true;
  }
};

// Gaussian prior on a turntable correction: value / sigma per component.
template <int N>
struct CorrectionPrior {
  double inv_sigma = 1;
  template <typename T>
  bool operator()(const T* x, T* r) const {
    for (int i = 0; i < N; ++i) r[i] = x[i] * T(inv_sigma);
    return true;
  }
};

}  // namespace s2r::reg
