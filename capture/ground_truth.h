// A session's ground_truth/ folder (docs/formats.md): what the synthetic rig
// knows exactly about the session it wrote. Stages that measure themselves
// against it (register, reconstruct, eval, preview) read it here, without
// depending on the simulator that writes it.
//
//   ground_truth/rig.json      format "s2r.synth_truth" v1: scene, layout,
//                              intrinsics, depth-to-colour, table axis, and per
//                              frame the true table angle and camera pose
//   ground_truth/geometry.ply  the scene's triangles in the world frame
//   ground_truth/strands.ply   round curves (the fuzzy scene), if any
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

// What ground_truth/rig.json holds.
struct GroundTruth {
  std::string scene;
  Layout layout = Layout::kObjectCentre;
  Intrinsics color, depth;
  Eigen::Isometry3d color_from_depth = Eigen::Isometry3d::Identity();
  Eigen::Vector3d axis_dir_camera = Eigen::Vector3d::UnitZ(), axis_point_camera = Eigen::Vector3d::Zero();
  std::vector<double> true_angle_deg;
  std::optional<Eigen::Isometry3d> world_from_board;  // the "board" scene
  std::vector<Eigen::Isometry3d> world_from_camera;  // colour camera, per frame
};

// ground_truth/rig.json of `session_dir`; not_found when the session has none.
Result<GroundTruth> load_ground_truth(const std::filesystem::path& session_dir);

// The truth's exact colour-camera poses when it has one per frame of a
// session of `frames` frames; nothing otherwise (a session without truth, or
// a truth of another session).
std::optional<std::vector<Eigen::Isometry3d>> ground_truth_poses(const std::filesystem::path& session_dir,
                                                                 size_t frames);

}  // namespace s2r
