// The octree over the fused surface (Wakatsuki, Ishii, Takahashi, Imai and Makino, 2003;
// docs/references.md).
//
// Samples are the fused signed distances at voxel centres; a cell is the cube
// between 8 samples (dual to the voxels). A cell holds surface when one of its
// 12 edges joins two observed samples of opposite sign (its edge-crossing
// flags F_e). Leaves are such cells; each level up merges 2x2x2 children.
// Per node:
//   v      representative vertex: the mean of the edge-crossing points below it
//   (n,th) normal cone, bottom-up: n = normalize(sum n_c), th = max(acos(n.n_c) + th_c)
//          (a leaf's cone holds the normals at its own crossings)
//   dE     shape error along n over the finest descendants,
//          max n.(v_i - v) - min n.(v_j - v), raised to the children's dE so it
//          never grows toward the leaves
// A cut of the tree gives a multi-scale patch mesh: every crossing edge of the
// finest level makes a quad between the representative vertices of the four
// cells around it, each replaced by its ancestor in the cut (collapsed quads
// become triangles or vanish). All patches share vertices, so nodes of
// different levels meet without cracks: a closed surface stays closed.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "reconstruct/model.h"

namespace s2r {

struct SdfSample {
  Eigen::Vector3i ijk;  // centre = ijk * voxel
  float sdf = 0;        // metres, negative inside
};

struct OctreeNode {
  Eigen::Vector3i origin = Eigen::Vector3i::Zero();  // first cell it covers (cell units)
  int level = 0;        // 0 = root
  int size = 1;         // cells per side: 2^(max_level - level)
  Eigen::Vector3f vertex = Eigen::Vector3f::Zero();
  Eigen::Vector3f normal = Eigen::Vector3f::UnitZ();
  float cone = 0;       // half-angle, radians, in [0, pi]
  float shape_error = 0;  // dE, metres
  uint16_t edge_flags = 0;  // leaves: which of the 12 cell edges cross the surface
  int32_t parent = -1;
  int32_t first_child = -1;  // children are contiguous
  uint8_t children = 0;
  uint32_t crossings = 0;    // crossing points below the node
};

// Where the surface crosses the grid edge from sample p to p + e_axis.
struct SurfaceCrossing {
  Eigen::Vector3i p;
  uint8_t axis = 0;
  bool inside_first = false;  // sdf(p) < 0
  float t = 0;                // the crossing at p + t e_axis, 0..1
  Eigen::Vector3f normal = Eigen::Vector3f::UnitZ();  // unit: the samples' gradients interpolated
};

// The gradient of the distances at sample p (distance sp) from its six
// neighbours through get(q) -> std::optional<float>: central where both
// exist, one-sided where one does, 0 along an axis with neither.
template <class Get>
Eigen::Vector3f sdf_gradient(const Eigen::Vector3i& p, float sp, Get&& get) {
  Eigen::Vector3f g = Eigen::Vector3f::Zero();
  for (int a = 0; a < 3; ++a) {
    const std::optional<float> lo = get(Eigen::Vector3i(p - Eigen::Vector3i::Unit(a))),
                               hi = get(Eigen::Vector3i(p + Eigen::Vector3i::Unit(a)));
    if (lo && hi) g[a] = (*hi - *lo) / 2;
    else if (hi) g[a] = *hi - sp;
    else if (lo) g[a] = sp - *lo;
  }
  return g;
}

// The crossing on the edge from sample p (distance sp) along `axis`, if the
// sample there has the other sign and differs by at most max_jump_voxels
// voxels (more is the truncation band's edge, not a surface).
template <class Get>
std::optional<SurfaceCrossing> crossing_at(const Eigen::Vector3i& p, int axis, float sp, double voxel,
                                           double max_jump_voxels, Get&& get) {
  const Eigen::Vector3i q = p + Eigen::Vector3i::Unit(axis);
  const std::optional<float> sq = get(q);
  if (!sq || ((sp < 0) == (*sq < 0)) || std::abs(sp - *sq) > max_jump_voxels * voxel) return std::nullopt;
  SurfaceCrossing c;
  c.p = p, c.axis = uint8_t(axis), c.inside_first = sp < 0;
  c.t = sp / (sp - *sq);
  const Eigen::Vector3f n = (1 - c.t) * sdf_gradient(p, sp, get) + c.t * sdf_gradient(q, *sq, get);
  c.normal = n.norm() > 1e-12f ? Eigen::Vector3f(n.normalized())
                               : Eigen::Vector3f(Eigen::Vector3f::Unit(axis) * (sp < 0 ? 1.f : -1.f));
  return c;
}

// Every crossing between the samples, in sample order (then by axis). Non-
// finite distances are no sample.
std::vector<SurfaceCrossing> find_crossings(const std::vector<SdfSample>& samples, double voxel, double max_jump_voxels);

class SurfaceOctree {
 public:
  // `max_jump_voxels`: samples whose distances differ by more than this many
  // voxels across an edge are not a crossing (a silhouette, not a surface).
  static SurfaceOctree build(const std::vector<SdfSample>& samples, double voxel, double max_jump_voxels = 2);
  // The same from the crossings (SparseVolume::crossings finds them in the
  // volume itself, in parallel).
  static SurfaceOctree build_from_crossings(const std::vector<SurfaceCrossing>& crossings, double voxel);

  const std::vector<OctreeNode>& nodes() const { return nodes_; }
  int max_level() const { return max_level_; }
  double voxel() const { return voxel_; }
  // Node origins are relative to this cell; add it for absolute cells (the
  // model file's OctreeRecord::origin).
  const Eigen::Vector3i& base_cell() const { return base_; }
  size_t leaves() const { return leaf_count_; }
  size_t crossings() const { return edges_.size(); }

  // The nodes whose shape error is at most `max_shape_error_m` (or leaves),
  // taken from the root down: a cut through the tree.
  std::vector<int> cut(double max_shape_error_m) const;
  // The crack-free patch mesh of a cut (all leaves when empty).
  Mesh patch_mesh(const std::vector<int>& cut = {}) const;

 private:
  struct CrossingEdge {
    Eigen::Vector3i p;  // lower sample
    uint8_t axis;
    bool inside_first;  // sdf(p) < 0
  };
  double voxel_ = 0;
  int max_level_ = 0;
  Eigen::Vector3i base_ = Eigen::Vector3i::Zero();  // cell coordinates are relative to this
  size_t leaf_count_ = 0;
  std::vector<OctreeNode> nodes_;
  std::vector<CrossingEdge> edges_;
  std::vector<int32_t> edge_cells_;  // 4 leaf node indices per crossing edge
};

// The tree as the model file's records (absolute cell origins), breadth first.
std::vector<OctreeRecord> octree_records(const SurfaceOctree& tree);

// Boundary edges of a triangle mesh (used by an odd number of triangles): 0
// for a closed surface.
size_t boundary_edges(const Mesh& mesh);

}  // namespace s2r
