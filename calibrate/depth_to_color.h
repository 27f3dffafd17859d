// The depth camera's pose in the colour camera (color_from_depth) from a board
// seen by both: the board's plane comes from its corners in the colour image
// (PnP), the depth camera sees the same plane as points. One Ceres problem
// over the rigid transform minimises the point-to-plane distances of the depth
// points inside the board (robust loss); two rounds, since which depth pixels
// lie on the board depends on the estimate.
#pragma once

#include <string>
#include <vector>

#include "calibrate/board.h"
#include "core/camera_model.h"
#include "core/image.h"
#include "core/report.h"

namespace s2r {

struct DepthColorView {
  BoardDetection color_detection;  // board corners in the colour image
  ImageU16 depth;                  // the depth frame taken with it
  std::string name;
};

struct DepthColorResult {
  Eigen::Isometry3d color_from_depth = Eigen::Isometry3d::Identity();
  double rms_m = 0;  // point-to-plane RMS over the board points
  size_t points = 0;
  Report report;
};

Result<DepthColorResult> calibrate_depth_to_color(const std::vector<DepthColorView>& views, const Intrinsics& color_K,
                                                  const Intrinsics& depth_K, double depth_unit_m,
                                                  const Eigen::Isometry3d& initial_color_from_depth);

}  // namespace s2r
