// What a session's frames need before any stage can use them, in one place:
// the camera pose of every frame (by one order of preference), the depth
// sensor the depth frames are read with, and each frame's colour
// intrinsics, each from a calibration where one is given. Register,
// reconstruct, eval and the preview all resolve them here.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "calibrate/calibration.h"
#include "capture/session.h"
#include "core/camera_model.h"
#include "core/result.h"

namespace s2r {

enum class PoseSource { poses_file, given, calibrated_axis, ground_truth };

// Camera poses for a session's frames (colour camera, world frame), in order of
// preference: a poses file; the frames' given poses (imports); table angles
// about a calibrated axis; the synthetic rig's ground truth. `kind` and
// `source` (in words, for reports) say which.
struct FramePoses {
  std::vector<std::optional<Eigen::Isometry3d>> world_from_camera;
  PoseSource kind = PoseSource::given;
  std::string source;
};
Result<FramePoses> resolve_frame_poses(const Session& s, const std::filesystem::path& poses_file,
                                       const std::filesystem::path& calibration_file);

// The depth sensor a session's depth frames are read with: the session's,
// with a calibration's depth intrinsics and depth-to-colour extrinsic in
// place of its own where the calibration has them.
struct DepthSensorModel {
  std::optional<Intrinsics> intrinsics;  // none: the session has no depth sensor
  Eigen::Isometry3d color_from_depth = Eigen::Isometry3d::Identity();
  double unit_m = 0.001;
};
DepthSensorModel resolve_depth_sensor(const Session& s, const Calibration* cal);

// A frame's colour intrinsics: the calibration's if it has them, else the
// session's (per frame or its colour sensor's); none if neither has any.
std::optional<Intrinsics> resolve_color_intrinsics(const Session& s, const Frame& f, const Calibration* cal);

}  // namespace s2r
