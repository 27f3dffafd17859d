// The whole job behind `s2r register`: load the views (a session or Stanford
// scans), optionally perturb the starting poses, register, and write the
// poses file, the .conf (for Stanford input), the convergence table and plot.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
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

Result<Report> run_register_job(const RegisterJob& job);

}  // namespace s2r
