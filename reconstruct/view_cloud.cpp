// PCL is confined to this translation unit (and the ICP peer).
#include "reconstruct/view_cloud.h"

#include <cmath>

#include <pcl/features/feature.h>
#include <pcl/features/normal_3d.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

namespace s2r {

namespace {

pcl::PointCloud<pcl::PointXYZ>::Ptr to_pcl(const std::vector<Eigen::Vector3f>& pts) {
  auto cloud = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  cloud->reserve(pts.size());
  for (const auto& p : pts) cloud->emplace_back(p.x(), p.y(), p.z());
  return cloud;
}

// Indices (into scan.points) that survive statistical outlier removal.
std::vector<uint8_t> inliers(const PointScan& scan, const PrepOptions& o) {
  std::vector<uint8_t> keep(scan.points.size(), 1);
  if (!o.remove_outliers || scan.points.size() <= static_cast<size_t>(o.outlier_k) + 1) return keep;
  auto cloud = to_pcl(scan.points);
  pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor(/*extract_removed_indices=*/true);
  sor.setInputCloud(cloud);
  sor.setMeanK(o.outlier_k);
  sor.setStddevMulThresh(o.outlier_std_mul);
  pcl::Indices kept;
  sor.filter(kept);
  for (auto i : *sor.getRemovedIndices()) keep[static_cast<size_t>(i)] = 0;
  return keep;
}

Eigen::Vector3f facing(Eigen::Vector3f n, const Eigen::Vector3f& p, const Eigen::Vector3f& viewpoint) {
  if (n.dot(viewpoint - p) < 0) n = -n;
  return n;
}

// Normals and edge flags from the range grid: PCA of the grid window around
// each point, over neighbours closer than the discontinuity gap.
void grid_normals(const PointScan& scan, const std::vector<uint8_t>& keep, const PrepOptions& o,
                  ViewCloud& out, PrepStats& st) {
  const int W = scan.grid_width, H = scan.grid_height, r = std::max(1, o.grid_radius);
  const int e = std::max(1, o.edge_cells), window_r = std::max(r, e);
  auto cloud = to_pcl(scan.points);
  const float gap2 = static_cast<float>(o.max_neighbour_gap_m * o.max_neighbour_gap_m);
  auto valid = [&](int x, int y) -> int {
    if (x < 0 || y < 0 || x >= W || y >= H) return -1;
    const int i = scan.grid_index[static_cast<size_t>(y) * W + x];
    return i >= 0 && keep[static_cast<size_t>(i)] ? i : -1;
  };
  pcl::Indices window;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const int c = valid(x, y);
      if (c < 0) continue;
      const Eigen::Vector3f& pc = scan.points[static_cast<size_t>(c)];
      window.clear();
      bool edge = false;
      for (int dy = -window_r; dy <= window_r; ++dy)
        for (int dx = -window_r; dx <= window_r; ++dx) {
          const int i = valid(x + dx, y + dy);
          const int cells = std::max(std::abs(dx), std::abs(dy));
          if (i < 0 || (scan.points[static_cast<size_t>(i)] - pc).squaredNorm() > gap2) {
            if (cells <= e) edge = true;
            continue;
          }
          if (cells <= r) window.push_back(i);
        }
      Eigen::Vector4f plane;
      float curvature = 0;
      if (window.size() < 5 || !pcl::computePointNormal(*cloud, window, plane, curvature) ||
          !std::isfinite(plane[0])) {
        ++st.no_normal;
        continue;
      }
      out.points.push_back(pc);
      out.normals.push_back(facing(plane.head<3>().normalized(), pc, o.viewpoint));
      out.edge.push_back(edge ? 1 : 0);
      st.edge += edge;
    }
}

// Normals from the k nearest neighbours (points without a grid); no edge flags.
void knn_normals(const PointScan& scan, const std::vector<uint8_t>& keep, const PrepOptions& o,
                 ViewCloud& out, PrepStats& st) {
  std::vector<Eigen::Vector3f> kept;
  for (size_t i = 0; i < scan.points.size(); ++i)
    if (keep[i]) kept.push_back(scan.points[i]);
  auto cloud = to_pcl(kept);
  pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> ne;
  ne.setInputCloud(cloud);
  ne.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  ne.setKSearch(std::max(5, o.normal_k));
  ne.setViewPoint(o.viewpoint.x(), o.viewpoint.y(), o.viewpoint.z());
  pcl::PointCloud<pcl::Normal> normals;
  ne.compute(normals);
  for (size_t i = 0; i < kept.size(); ++i) {
    const auto& n = normals[i];
    if (!std::isfinite(n.normal_x)) {
      ++st.no_normal;
      continue;
    }
    out.points.push_back(kept[i]);
    out.normals.push_back(Eigen::Vector3f(n.normal_x, n.normal_y, n.normal_z).normalized());
    out.edge.push_back(0);
  }
}

}  // namespace

Result<ViewCloud> prepare_view(const PointScan& scan, const PrepOptions& o, PrepStats* stats) {
  PrepStats st;
  st.input = scan.points.size();
  for (const auto& p : scan.points)
    if (!p.allFinite()) return fail("view has a non-finite point");
  const bool gridded = scan.grid_width > 0 && scan.grid_height > 0 &&
                       scan.grid_index.size() == static_cast<size_t>(scan.grid_width) * scan.grid_height;
  ViewCloud out;
  if (!scan.points.empty()) {
    const auto keep = inliers(scan, o);
    for (auto k : keep) st.outliers += k ? 0 : 1;
    if (gridded)
      grid_normals(scan, keep, o, out, st);
    else
      knn_normals(scan, keep, o, out, st);
  }
  st.kept = out.size();
  if (stats) *stats = st;
  return out;
}

ViewCloud downsample(const ViewCloud& full, double voxel_m) {
  if (voxel_m <= 0 || full.size() == 0) return full;
  auto cloud = pcl::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  cloud->reserve(full.size());
  for (size_t i = 0; i < full.size(); ++i) {
    pcl::PointNormal p;
    p.getVector3fMap() = full.points[i];
    p.getNormalVector3fMap() = full.normals[i];
    p.curvature = full.edge[i];  // averaged: > 0 when any member is an edge
    cloud->push_back(p);
  }
  pcl::VoxelGrid<pcl::PointNormal> grid;
  grid.setInputCloud(cloud);
  const float leaf = static_cast<float>(voxel_m);
  grid.setLeafSize(leaf, leaf, leaf);
  grid.setDownsampleAllData(true);
  pcl::PointCloud<pcl::PointNormal> down;
  grid.filter(down);
  ViewCloud out;
  for (const auto& p : down) {
    const Eigen::Vector3f n = p.getNormalVector3fMap();
    if (!(n.norm() > 0.3f)) continue;  // normals in the voxel disagree: a crease or noise
    out.points.push_back(p.getVector3fMap());
    out.normals.push_back(n.normalized());
    out.edge.push_back(p.curvature > 0 ? 1 : 0);
  }
  return out;
}

struct NeighbourIndex::Impl {
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  bool empty = true;
};

NeighbourIndex::NeighbourIndex(const std::vector<Eigen::Vector3f>& points) : impl_(std::make_unique<Impl>()) {
  if (points.empty()) return;
  impl_->tree.setInputCloud(to_pcl(points));
  impl_->empty = false;
}
NeighbourIndex::~NeighbourIndex() = default;
NeighbourIndex::NeighbourIndex(NeighbourIndex&&) noexcept = default;
NeighbourIndex& NeighbourIndex::operator=(NeighbourIndex&&) noexcept = default;

int NeighbourIndex::nearest(const Eigen::Vector3f& q, float max_dist, float* dist2) const {
  if (impl_->empty) return -1;
  // A radius search with one neighbour: the nearest within reach, and a query
  // far from every point is cut short instead of searching the whole tree.
  pcl::Indices idx;
  std::vector<float> d2;
  pcl::PointXYZ p(q.x(), q.y(), q.z());
  if (impl_->tree.radiusSearch(p, max_dist, idx, d2, 1) < 1) return -1;
  if (dist2) *dist2 = d2[0];
  return idx[0];
}

}  // namespace s2r
