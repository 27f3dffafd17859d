// Pre-processing of one view's points for registration (PCL): outlier
// removal, normals (from the range grid where the scan has one), scan-edge
// flags, voxel down-sampling, and a k-d tree for nearest-neighbour queries.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "core/result.h"

namespace s2r {

// Points of one view in its sensor frame, with unit normals facing the sensor.
struct ViewCloud {
  std::vector<Eigen::Vector3f> points;
  std::vector<Eigen::Vector3f> normals;
  // 1 = the point lies next to a hole of the range grid (edge of the scan or
  // of an occlusion): correspondences onto it are unreliable and rejected.
  std::vector<uint8_t> edge;
  size_t size() const { return points.size(); }
};

struct PrepOptions {
  // Statistical outlier removal: a point whose mean distance to its k
  // neighbours exceeds mean + std_mul * stddev over the view is removed.
  bool remove_outliers = true;
  int outlier_k = 16;
  double outlier_std_mul = 2.0;
  // Normals: on a range grid, a window of (2*grid_radius+1)^2 grid cells; else
  // the k nearest neighbours.
  int grid_radius = 2;
  int normal_k = 16;
  // Grid neighbours farther than this are a depth discontinuity, not surface.
  double max_neighbour_gap_m = 0.01;
  // On a range grid, a point within this many cells of a hole or a
  // discontinuity is an edge: kept, but never matched in registration. A
  // laser-stripe scanner's samples bend away from the surface near a
  // silhouette (Curless and Levoy's VRIP down-weights them for the same
  // reason); `load_stanford_views` uses 3. One cell keeps the thin overlap
  // strips of views far apart, which wider edges would erase (the rig's four
  // views 90 deg apart).
  int edge_cells = 1;
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();  // sensor origin, in the scan's frame
};

struct PrepStats {
  size_t input = 0, outliers = 0, no_normal = 0, edge = 0, kept = 0;
};

// Full-resolution view: outliers removed, normals, edge flags.
Result<ViewCloud> prepare_view(const PointScan& scan, const PrepOptions& options,
                               PrepStats* stats = nullptr);

// Voxel-grid down-sampling (centroid per voxel; normals averaged and
// renormalised; a voxel is an edge if any point in it is).
ViewCloud downsample(const ViewCloud& full, double voxel_m);

// Nearest-neighbour queries over a fixed set of points (PCL k-d tree).
class NeighbourIndex {
 public:
  explicit NeighbourIndex(const std::vector<Eigen::Vector3f>& points);
  ~NeighbourIndex();
  NeighbourIndex(NeighbourIndex&&) noexcept;
  NeighbourIndex& operator=(NeighbourIndex&&) noexcept;
  // Index of the nearest point within `max_dist`, or -1; `dist2` its squared distance.
  int nearest(const Eigen::Vector3f& q, float max_dist, float* dist2 = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace s2r
