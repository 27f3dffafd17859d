// COLMAP's sparse model (cameras, images, points3D), text or binary, as
// COLMAP 3.8 writes them (docs/formats.md): read into this project's camera
// conventions.
//
// COLMAP's poses are cam_from_world (quaternion w x y z, translation) in
// OpenCV's camera axes; its pixel centres lie at (i + 0.5, j + 0.5), so cx
// and cy move by -0.5 into Intrinsics (pixel centres at integers).
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/result.h"

namespace s2r {

struct ColmapCamera {
  Intrinsics K;
  std::string model;  // SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL or OPENCV
};
struct ColmapImage {
  uint32_t id = 0, camera = 0;
  std::string name;
  Eigen::Isometry3d cam_from_world = Eigen::Isometry3d::Identity();
  size_t points2d = 0;
};
struct ColmapModel {
  std::map<uint32_t, ColmapCamera> cameras;
  std::vector<ColmapImage> images;  // in the file's order
  size_t points3d = 0;
  double mean_track_error_px = 0;
  std::string encoding;  // "text" or "binary"
};

// `dir` holds cameras.{txt,bin}, images.{txt,bin} and optionally points3D;
// binary when cameras.bin and images.bin are both there. Other camera models
// are refused by name (ErrorCode::unsupported); every count in a binary file is
// checked against the bytes left before anything is allocated.
Result<ColmapModel> read_colmap_model(const std::filesystem::path& dir);

}  // namespace s2r
