// Inputs of the registration: views from a capture session (depth images or
// scanner points, initial poses from the turntable angle and calibrated axis
// or the session's given poses) or from Stanford range scans and their .conf.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "calibrate/calibration.h"
#include "capture/session.h"
#include "capture/stanford_conf.h"
#include "reconstruct/registration.h"

namespace s2r {

struct RegistrationInput {
  std::vector<RegistrationView> views;
  std::vector<Eigen::Isometry3d> given;  // the input's poses (before any perturbation)
  std::vector<int> frames;               // session frame index of each view
  std::optional<TurntablePrior> turntable;  // world-frame axis, when calibrated
  std::optional<StanfordConf> conf;          // --stanford: written back with the result
  PrepStats prep;                            // summed over views
  std::vector<std::string> notes;
};

Result<RegistrationInput> load_stanford_views(const std::filesystem::path& conf, const PrepOptions& prep);

// Initial poses: the calibration's axis and each frame's reported table angle
// when `calibration` has an axis, else the poses the session gives.
Result<RegistrationInput> load_session_views(const Session& session, const Calibration* calibration,
                                             const PrepOptions& prep);

// Each pose except `fixed` is turned by exactly `deg` about a random axis
// through `centre` and shifted by exactly `m` in a random direction
// (deterministic per seed).
std::vector<Eigen::Isometry3d> perturb_poses(const std::vector<Eigen::Isometry3d>& poses, double deg, double m,
                                             uint64_t seed, const Eigen::Vector3d& centre, int fixed = 0);

}  // namespace s2r
