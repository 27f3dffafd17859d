// The model the viewer loads (docs/formats.md, "Model"):
//
//   MODEL/model.json        header: version, voxel size, bounds, cameras,
//                           payload files with record counts and CRC-32
//   MODEL/facets.bin        FacetRecord[] (little-endian, 40 bytes each)
//   MODEL/facet_cameras.bin uint32[]: camera indices, FacetRecord ranges into it
//   MODEL/cameras/NNNN.exr  per-camera RGBA + depth textures (later stages)
//
// Every payload starts with a 24-byte header: magic "S2RB", payload version,
// record size, record count; and ends with the CRC-32 of everything before.
// Loading rejects a truncated or inconsistent model, naming file and field.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/result.h"

namespace s2r {

inline constexpr int kModelVersion = 1;

struct FacetRecord {
  float center[3];       // world, metres
  float size;            // voxel width w (the billboard is >= sqrt(3) w wide)
  float normal[3];       // unit, or 0 where unknown
  float reliability;     // 0..1 agreement between views
  uint32_t first_camera; // range in facet_cameras
  uint32_t camera_count;
};
static_assert(sizeof(FacetRecord) == 40, "FacetRecord is an on-disk layout");

struct ModelCamera {
  Intrinsics intrinsics;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  std::string texture;  // relative path of the RGBA+depth texture, may be empty
  int session_frame = -1;
};

struct Model {
  double voxel_size_m = 0;
  Eigen::AlignedBox3d bounds;
  std::vector<ModelCamera> cameras;
  std::vector<FacetRecord> facets;
  std::vector<uint32_t> facet_cameras;
  std::optional<std::string> patch_mesh;  // relative PLY path
  std::optional<std::string> environment;  // relative path
};

Result<Model> load_model(const std::filesystem::path& dir);
Status save_model(const std::filesystem::path& dir, const Model& model);

}  // namespace s2r
