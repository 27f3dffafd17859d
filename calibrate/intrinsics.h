// Camera intrinsics from board views (OpenCV calibrateCamera): detection with
// sub-pixel refinement, rejection of views that make the fit worse, a report
// with the RMS reprojection error, per-view errors, parameter standard
// deviations and seconds. Weak data gives a bounded answer plus a warning
// (fewer parameters are estimated), or a clear error — never NaN.
#pragma once

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include "calibrate/board.h"
#include "calibrate/calibration.h"
#include "core/report.h"

namespace s2r {

struct IntrinsicsOptions {
  BoardSpec board;
  double reject_factor = 3.0;  // a view whose RMS exceeds factor x the median is dropped
  int min_views = 3;           // below this, principal point and higher distortion are fixed
  bool fix_k3 = false;         // most lenses need no k3; fixing it steadies fits from few poses
};

struct ViewResult {
  std::string name;
  bool detected = false, used = false;
  double rms_px = 0;
  std::string note;
};

struct IntrinsicsResult {
  SensorCalibration calibration;
  std::vector<ViewResult> views;
  // Standard deviations: fx fy cx cy k1 k2 p1 p2 k3 (0 where fixed).
  std::array<double, 9> stddev{};
  Report report;
};

// Views already detected (tests, the rig); names label the report.
Result<IntrinsicsResult> calibrate_intrinsics(const std::vector<BoardDetection>& views,
                                              const std::vector<std::string>& names, int width, int height,
                                              const IntrinsicsOptions& options);
// From image files (`s2r calibrate intrinsics --images GLOB`).
Result<IntrinsicsResult> calibrate_intrinsics_from_files(const std::vector<std::filesystem::path>& images,
                                                         const IntrinsicsOptions& options);

}  // namespace s2r
