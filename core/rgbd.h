// Depth image -> points, coloured from a colour camera beside the depth camera.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/mesh.h"

namespace s2r {

struct ColoredPoints {
  std::vector<Eigen::Vector3f> points;            // in the colour camera's frame
  std::vector<std::array<uint8_t, 3>> colors;     // grey (128) where colour is unknown
};

// depth: 16-bit, `unit_m` metres per count, 0 = no measurement.
// Points are expressed in the colour camera's frame (color_from_depth * p_depth);
// each takes the colour of the pixel it projects to, when inside the image.
ColoredPoints depth_to_points(const ImageU16& depth, double unit_m, const Intrinsics& depth_K,
                              const Eigen::Isometry3d& color_from_depth, const ImageU8* color,
                              const Intrinsics* color_K, int stride = 1);

// The depth image as a range grid (one cell per depth pixel, -1 where there
// is no measurement), points in the colour camera's frame.
PointScan depth_to_scan(const ImageU16& depth, double unit_m, const Intrinsics& depth_K,
                        const Eigen::Isometry3d& color_from_depth);

}  // namespace s2r
