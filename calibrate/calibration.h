// Calibration results on disk (docs/formats.md, "Calibration"):
// intrinsics per sensor, the depth->colour extrinsic and the turntable axis,
// each with the residual it was fitted to. Format "s2r.calibration".
#pragma once

#include <filesystem>
#include <optional>
#include <vector>

#include <Eigen/Geometry>

#include "capture/session.h"
#include "core/camera_model.h"
#include "core/result.h"

namespace s2r {

inline constexpr int kCalibrationVersion = 1;

struct SensorCalibration {
  Intrinsics intrinsics;
  double rms_px = 0;  // reprojection RMS of the fit
  int views = 0;
};

struct TurntableAxis {
  Eigen::Vector3d direction_camera = Eigen::Vector3d::UnitZ();  // unit, colour camera frame
  Eigen::Vector3d point_camera = Eigen::Vector3d::Zero();       // a point on the axis
  double rms_m = 0;  // residual of the board poses about the fitted axis
  std::vector<double> step_angles_deg;  // measured angle per calibration step
};

struct Calibration {
  std::optional<SensorCalibration> color, depth;
  std::optional<Eigen::Isometry3d> color_from_depth;
  double color_from_depth_rms = 0;
  std::optional<TurntableAxis> axis;

  // Initial pose of a frame at table angle `angle_deg` (world = table frame at
  // angle 0, which is the colour camera frame rotated onto the axis): for an
  // object-centre session the object turns by +angle, so the camera turns by
  // -angle about the axis in the object's frame.
  Eigen::Isometry3d world_from_camera_at(double angle_deg, Layout layout) const;
};

Result<Calibration> load_calibration(const std::filesystem::path& path);
Status save_calibration(const std::filesystem::path& path, const Calibration& c);  // atomic

}  // namespace s2r
