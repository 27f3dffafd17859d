// The surface octree's invariants (docs/references.md: Wakatsuki et al. 2003): each node's normal
// cone holds its children's cones; dE >= 0 and never grows toward the leaves;
// patch meshes of cuts through different levels leave no cracks (a closed
// surface stays closed); opposite normals open the cone to pi.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "reconstruct/octree.h"

using namespace s2r;

namespace {

// Signed distance samples of a sphere in a band around its surface.
std::vector<SdfSample> sphere(double r_vox, const Eigen::Vector3d& c_vox, double voxel, double band = 3) {
  std::vector<SdfSample> out;
  const int R = int(std::ceil(r_vox + band)) + 1;
  for (int x = -R; x <= R; ++x)
    for (int y = -R; y <= R; ++y)
      for (int z = -R; z <= R; ++z) {
        const Eigen::Vector3i ijk = Eigen::Vector3i(x, y, z) + c_vox.array().round().cast<int>().matrix();
        const double d = (ijk.cast<double>() - c_vox).norm() - r_vox;
        if (std::abs(d) <= band) out.push_back({ijk, float(d * voxel)});
      }
  return out;
}

}  // namespace

TEST(Octree, ConesNestAndShapeErrorShrinks) {
  const double w = 0.002;
  const SurfaceOctree t = SurfaceOctree::build(sphere(13.3, {0.4, -0.2, 0.1}, w), w);
  ASSERT_GT(t.nodes().size(), 100u);
  EXPECT_GE(t.max_level(), 5);
  size_t leaves = 0;
  for (const auto& n : t.nodes()) {
    EXPECT_GE(n.shape_error, 0.f);
    EXPECT_TRUE(std::isfinite(n.cone));
    EXPECT_LE(n.cone, float(std::numbers::pi) + 1e-6f);
    if (n.children == 0) {
      ++leaves;
      EXPECT_EQ(n.shape_error, 0.f);
      EXPECT_NE(n.edge_flags, 0);
      continue;
    }
    for (int c = n.first_child; c < n.first_child + n.children; ++c) {
      const OctreeNode& ch = t.nodes()[size_t(c)];
      EXPECT_EQ(ch.level, n.level + 1);
      // A cone of pi holds every direction.
      if (n.cone < float(std::numbers::pi) - 1e-6f) {
        EXPECT_LE(std::acos(std::clamp(n.normal.dot(ch.normal), -1.f, 1.f)) + ch.cone, n.cone + 1e-5f);
      }
      EXPECT_GE(n.shape_error, ch.shape_error);
    }
  }
  EXPECT_EQ(leaves, t.leaves());
  // On a sphere a node spanning angle 2a has dE close to r (1 - cos a); the
  // root spans everything: dE about the diameter.
  EXPECT_NEAR(t.nodes()[0].shape_error, 2 * 13.3 * w, 2 * w);
  EXPECT_NEAR(t.nodes()[0].cone, std::numbers::pi, 0.05);
}

TEST(Octree, PatchMeshesOfEveryCutAreClosed) {
  const double w = 0.002, r = 11.7;
  const Eigen::Vector3d c(0.3, 0.1, -0.4);
  const SurfaceOctree t = SurfaceOctree::build(sphere(r, c, w), w);
  const Mesh fine = t.patch_mesh();
  ASSERT_GT(fine.faces.size(), 1000u);
  EXPECT_EQ(boundary_edges(fine), 0u);
  size_t previous = fine.faces.size();
  for (double T : {0.25 * w, 0.5 * w, w, 2 * w, 4 * w}) {
    const auto cut = t.cut(T);
    // The cut mixes levels.
    int lo = 99, hi = -1;
    for (int i : cut) lo = std::min(lo, t.nodes()[size_t(i)].level), hi = std::max(hi, t.nodes()[size_t(i)].level);
    const Mesh m = t.patch_mesh(cut);
    SCOPED_TRACE("T = " + std::to_string(T / w) + " voxels, levels " + std::to_string(lo) + ".." + std::to_string(hi));
    EXPECT_EQ(boundary_edges(m), 0u);  // no cracks between levels
    EXPECT_LE(m.faces.size(), previous);
    previous = m.faces.size();
    // Vertices stay near the sphere: within the cut's tolerance plus a voxel.
    for (const auto& v : m.vertices) EXPECT_NEAR((v.cast<double>() / w - c).norm(), r, T / w + 1.0);
  }
  EXPECT_LT(previous, fine.faces.size() / 4);
}

TEST(Octree, FlatSurfaceHasNoShapeError) {
  const double w = 0.001;
  std::vector<SdfSample> plane;
  for (int x = 0; x < 32; ++x)
    for (int y = 0; y < 32; ++y)
      for (int z = -2; z <= 2; ++z) plane.push_back({{x, y, z}, float((z - 0.3) * w)});
  const SurfaceOctree t = SurfaceOctree::build(plane, w);
  for (const auto& n : t.nodes()) {
    EXPECT_LT(n.shape_error, 1e-6f);
    EXPECT_LT(n.cone, 1e-3f);
    EXPECT_GT(n.normal.z(), 0.999f);
  }
  EXPECT_EQ(t.cut(1e-5).size(), 1u);  // the root is enough
}

TEST(Octree, OppositeNormalsOpenTheConeToPi) {
  // A slab two voxels thick: its two faces point opposite ways.
  const double w = 0.001;
  std::vector<SdfSample> slab;
  for (int x = 0; x < 8; ++x)
    for (int y = 0; y < 8; ++y)
      for (int z = -3; z <= 3; ++z) slab.push_back({{x, y, z}, float((std::abs(z + 0.0) - 1.0) * w)});
  const SurfaceOctree t = SurfaceOctree::build(slab, w);
  ASSERT_FALSE(t.nodes().empty());
  EXPECT_NEAR(t.nodes()[0].cone, std::numbers::pi, 1e-6);
  EXPECT_TRUE(t.nodes()[0].normal.allFinite());
  EXPECT_GE(t.nodes()[0].shape_error, 1.9f * float(w));
}

TEST(Octree, EmptyAndDegenerateInput) {
  EXPECT_TRUE(SurfaceOctree::build({}, 0.001).nodes().empty());
  EXPECT_TRUE(SurfaceOctree::build({}, 0.001).patch_mesh().faces.empty());
  // NaN distances are ignored; a jump larger than the limit is not a crossing.
  const SurfaceOctree t = SurfaceOctree::build({{{0, 0, 0}, std::nanf("")}, {{1, 0, 0}, 0.01f}, {{2, 0, 0}, -0.01f}}, 0.001);
  EXPECT_EQ(t.crossings(), 0u);
}

// The model file's records carry absolute cells: every node's vertex lies in
// the cube its origin and level name (cell i spans the samples i..i+1).
TEST(Octree, RecordsUseAbsoluteCells) {
  const double w = 0.002;
  const SurfaceOctree t = SurfaceOctree::build(sphere(9.2, {40.3, -17.6, 5.1}, w), w);
  const auto records = octree_records(t);
  ASSERT_EQ(records.size(), t.nodes().size());
  for (const auto& r : records) {
    const int cells = 1 << (t.max_level() - r.level);
    for (int k = 0; k < 3; ++k) {
      EXPECT_GE(r.vertex[k] / w, r.origin[k] - 1e-3);
      EXPECT_LE(r.vertex[k] / w, r.origin[k] + cells + 1e-3);
    }
  }
}
