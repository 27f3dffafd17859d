// The whole job behind `s2r reconstruct`: a session and its poses in, a model
// out (docs/formats.md, "Model"): fusion, microfacets with per-region size,
// per-camera RGBA + depth textures, the fused surface mesh, and a report with
// the seconds of every step, counts, memory, voxel sizes and what was skipped.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "capture/session.h"
#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct ReconstructJob {
  std::filesystem::path session;
  std::filesystem::path out;          // the model folder
  std::filesystem::path poses;        // optional: registered poses (s2r register)
  std::filesystem::path calibration;  // optional: intrinsics, depth extrinsic, table axis
  std::optional<double> voxel_m;      // nullopt: from the error bound (--voxel auto)
  std::string geometry = "auto";      // auto | depth | hull | both
  std::vector<int> holdout;           // frames left out entirely
  double target_error_px = 0.5;       // on-screen texel error the auto voxel keeps under
  double truncation_voxels = 4;       // tau in voxels
  bool per_region = true;             // unreliable / fuzzy regions get 2x larger facets
  bool textures = true;               // write cameras/NNNN.exr
  int threads = 0;
  bool quiet = false;
};

// Camera poses for a session's frames (colour camera, world frame), in order of
// preference: a poses file; the frames' given poses (imports); table angles
// about a calibrated axis; the synthetic rig's ground truth. `source` says which.
struct FramePoses {
  std::vector<std::optional<Eigen::Isometry3d>> world_from_camera;
  std::string source;
};
Result<FramePoses> resolve_frame_poses(const Session& s, const std::filesystem::path& poses_file,
                                       const std::filesystem::path& calibration_file);

Result<Report> run_reconstruct_job(const ReconstructJob& job);

}  // namespace s2r
