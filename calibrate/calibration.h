// Calibration results on disk (docs/formats.md, "Calibration"):
// intrinsics per sensor, the depth->colour extrinsic and the turntable axis,
// each with the residual it was fitted to. Format "s2r.calibration".
#pragma once

#include <filesystem>
#include <optional>
#include <string>
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
  // Measured from a session's own images (s2r calibrate markers): the table
  // angle of each of its frames, in frame order, tied to the session's name.
  // Registration uses them instead of the frames' reported angles when the
  // name and the frame count match.
  std::vector<double> frame_angles_deg;
  std::string frames_session;
  // The turntable's radius where known (markers; 0 = unknown). Then depth
  // outside its cylinder (farther from the axis, or below its plane through
  // point_camera) is background that does not turn with the object.
  double table_radius_m = 0;
  bool over_table(const Eigen::Vector3d& p_camera, double below_m = 0.005) const {
    const Eigen::Vector3d v = p_camera - point_camera;
    const double h = direction_camera.dot(v);
    return h >= -below_m && (v - h * direction_camera).norm() <= table_radius_m;
  }
};

// Zeroes the depth pixels that are not over the table (see
// TurntableAxis::table_radius_m; nothing when the radius is unknown);
// returns how many.
size_t mask_off_table(ImageU16& depth, double unit_m, const Intrinsics& depth_K, const Eigen::Isometry3d& color_from_depth,
                      const TurntableAxis& axis);

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
  // Whether the axis carries angles measured from this session's own frames
  // (same name and frame count), and frame i's table angle: measured when
  // so, else the frame's reported angle.
  bool has_measured_angles(const Session& s) const {
    return axis && !axis->frame_angles_deg.empty() && axis->frames_session == s.name &&
           axis->frame_angles_deg.size() == s.frames.size();
  }
  double frame_angle_deg(const Session& s, size_t i) const {
    return has_measured_angles(s) ? axis->frame_angles_deg[i] : s.frames[i].table_angle_reported_deg;
  }
};

Result<Calibration> load_calibration(const std::filesystem::path& path);
Status save_calibration(const std::filesystem::path& path, const Calibration& c);  // atomic

}  // namespace s2r
