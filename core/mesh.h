// Triangle meshes and point scans, and their PLY files (read and written
// through PCL's PLY reader/writer).
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/result.h"

namespace s2r {

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3i> faces;
  std::vector<Eigen::Vector3f> normals;  // per vertex; empty until computed
  std::vector<Eigen::Vector3f> colors;   // per vertex, 0..1; empty when the PLY has none

  void compute_vertex_normals();  // area-weighted
  Eigen::AlignedBox3f bounds() const;
  void transform(const Eigen::Isometry3d& t);
};

// A scan's points. Range scans keep their grid: grid_index[row * grid_width +
// col] is the point index or -1 (no return).
struct PointScan {
  std::vector<Eigen::Vector3f> points;
  int grid_width = 0, grid_height = 0;
  std::vector<int32_t> grid_index;
};

Result<Mesh> read_ply_mesh(const std::filesystem::path& path);
Result<PointScan> read_ply_points(const std::filesystem::path& path);
Status write_ply_mesh(const std::filesystem::path& path, const Mesh& mesh);      // binary, atomic
Status write_ply_points(const std::filesystem::path& path, const PointScan& scan);  // binary, atomic

}  // namespace s2r
