// Registered poses on disk (docs/formats.md, "Poses"): camera-to-world per
// frame with the registration residuals. Format "s2r.poses".
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/result.h"

namespace s2r {

inline constexpr int kPosesVersion = 1;

struct FramePose {
  int index = 0;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  double residual_rms_m = 0;  // point-to-plane RMS of this view's correspondences
  bool flagged = false;        // implausible residual/overlap: do not trust
  std::string note;
};

struct Poses {
  std::string session;  // the session folder these poses belong to (informative)
  double rms_m = 0;     // over all correspondences
  std::vector<FramePose> frames;
};

Result<Poses> load_poses(const std::filesystem::path& path);
Status save_poses(const std::filesystem::path& path, const Poses& poses);  // atomic

}  // namespace s2r
