// The whole job behind `s2r register`: load the views (a session or Stanford
// scans), optionally perturb the starting poses, register, and write the
// poses file, the .conf (for Stanford input), the convergence table and plot.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/report.h"
#include "reconstruct/registration.h"

namespace s2r {

struct RegisterJob {
  std::filesystem::path session;        // a capture session, or
  std::filesystem::path stanford_conf;  // Stanford range scans and their .conf
  std::filesystem::path calibration;    // optional: axis (initial poses, turntable mode), intrinsics
  std::filesystem::path out;            // folder: poses.json, convergence.csv/png, NAME.conf
  RegistrationOptions options;
  std::optional<double> perturb_deg, perturb_m;
  uint64_t seed = 1;
  std::string fixed_name;  // the view held fixed (default: the first)
  double table_sigma_deg = 0.2;  // turntable mode: the table angle's repeatability

  // The options' own ranges, an error naming the field ("table_sigma_deg:
  // must be > 0 degrees"); what depends on the input is checked by the job.
  Status validate() const;
};

// How far registered poses lie from a turntable's own (its table angles
// about the calibrated axis), per view: the turn about the axis (signed,
// right-handed) and the tilt off it, degrees.
struct TableAgreement {
  std::vector<double> turn_deg, tilt_deg;
  double max_turn_deg = 0, rms_turn_deg = 0, max_tilt_deg = 0;
};
TableAgreement table_agreement(const std::vector<Eigen::Isometry3d>& poses, const std::vector<Eigen::Isometry3d>& table,
                               const Eigen::Vector3d& axis);

// What run_register_job measured, typed (Ceres' Solver::Summary the model);
// report.json is to_report().
struct RegisterSummary {
  RegistrationMode mode = RegistrationMode::kFree;
  std::string fixed_view;                    // the view held fixed
  size_t views = 0, points_in = 0, points_kept = 0;
  double rms_m = 0;                          // point-to-plane over every overlapping pair
  int iterations = 0, rounds = 0;
  std::optional<TableAgreement> table;       // against the turntable's angles, when calibrated and not perturbed
  std::optional<PoseError> start_error, error;  // against the reference (the rig's truth or the unperturbed input)
  double seconds = 0, register_seconds = 0;  // the job, the solve alone
  Report report;

  const Report& to_report() const { return report; }
  std::string brief() const { return report.brief(); }
};

Result<RegisterSummary> run_register_job(const RegisterJob& job);

}  // namespace s2r
