// The turntable axis from board views at known table angles (Ceres).
//
// Model: the board stands on the table, so at table angle a_i
//   camera_from_board_i = A(phi_i) * camera_from_board_0,
// where A(phi) rotates by phi about the axis (unit direction d through point p,
// both in the colour camera frame) and phi_i is the angle the table really
// turned (phi_0 = a_0 fixes the gauge). One Ceres problem over d (sphere
// manifold), p (its component along d held by a weak prior), the board pose
// (quaternion manifold + translation) and every phi_i, minimising the
// reprojection error of all corners with a robust (Huber) loss. Initialised
// from per-view PnP poses: d from the relative rotations, p by least squares.
#pragma once

#include <string>
#include <vector>

#include "calibrate/board.h"
#include "calibrate/calibration.h"
#include "core/report.h"

namespace s2r {

struct AxisView {
  double commanded_deg = 0;
  BoardDetection detection;
  std::string name;
};

struct AxisOptions {
  double huber_px = 1.0;
  double warn_step_error_deg = 0.2;  // per-step |measured - commanded| that earns a warning
};

struct AxisResult {
  TurntableAxis axis;                  // step_angles_deg: measured angle of every used view
  std::vector<double> commanded_deg;   // of the used views
  std::vector<std::string> used;       // names of the used views
  Eigen::Isometry3d camera_from_board0 = Eigen::Isometry3d::Identity();
  double rms_px = 0;
  // The closed-form start from per-view PnP (a peer for the refined axis).
  Eigen::Vector3d initial_direction = Eigen::Vector3d::UnitZ(), initial_point = Eigen::Vector3d::Zero();
  Report report;
};

Result<AxisResult> calibrate_turntable_axis(const std::vector<AxisView>& views, const Intrinsics& K,
                                            const AxisOptions& options = {});

// Rotation axis through a set of camera poses (e.g. a calibrated ring of
// cameras): direction, point, RMS distance of the camera centres from their
// circle, and each pose's angle about the axis relative to the first.
struct PoseAxisFit {
  Eigen::Vector3d direction, point;
  double rms_m = 0;
  std::vector<double> angles_deg;
};
Result<PoseAxisFit> fit_axis_to_poses(const std::vector<Eigen::Isometry3d>& world_from_camera);

}  // namespace s2r
