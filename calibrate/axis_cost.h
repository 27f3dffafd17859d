// The axis fit's cost (internal to calibrate/, shared with its gradient test).
#pragma once

#include <ceres/rotation.h>

#include <Eigen/Geometry>

#include "core/camera_model.h"

namespace s2r {

// Reprojection of one board corner seen at table angle phi. Automatic
// derivatives; axis_cost_test.cpp checks them against numeric ones.
struct AxisReprojection {
  AxisReprojection(const Eigen::Vector2d& obs, const Eigen::Vector3d& X, const Intrinsics& K) : obs_(obs), X_(X), K_(K) {}
  template <class T>
  bool operator()(const T* d, const T* p, const T* q, const T* t, const T* phi, T* r) const {
    // Board point in the camera at angle 0 (q: Eigen order x y z w).
    const Eigen::Quaternion<T> qb(q[3], q[0], q[1], q[2]);
    const Eigen::Matrix<T, 3, 1> Y0 = qb * X_.cast<T>() + Eigen::Matrix<T, 3, 1>(t[0], t[1], t[2]);
    // Rotate about the axis (d through p) by phi.
    const T aa[3] = {d[0] * phi[0], d[1] * phi[0], d[2] * phi[0]};
    const T rel[3] = {Y0[0] - p[0], Y0[1] - p[1], Y0[2] - p[2]};
    T Y[3];
    ceres::AngleAxisRotatePoint(aa, rel, Y);
    for (int k = 0; k < 3; ++k) Y[k] += p[k];
    if (Y[2] <= T(1e-9)) return false;
    const T x = Y[0] / Y[2], y = Y[1] / Y[2];
    const T r2 = x * x + y * y;
    const auto& D = K_.dist;
    const T radial = T(1) + r2 * (T(D[0]) + r2 * (T(D[1]) + r2 * T(D[4])));
    const T xd = x * radial + T(2 * D[2]) * x * y + T(D[3]) * (r2 + T(2) * x * x);
    const T yd = y * radial + T(D[2]) * (r2 + T(2) * y * y) + T(2 * D[3]) * x * y;
    r[0] = T(K_.fx) * xd + T(K_.cx) - T(obs_.x());
    r[1] = T(K_.fy) * yd + T(K_.cy) - T(obs_.y());
    return true;
  }
  Eigen::Vector2d obs_;
  Eigen::Vector3d X_;
  Intrinsics K_;
};


}  // namespace s2r
