// The billboards' octree level of detail (render/facet_lod.h) on a sphere
// whose facets sit at the voxels around its surface: node billboards cover
// what they stand for, the normal cone culls only what the per-facet test
// would, thresholds trade facets monotonically, the visual field leaves out
// what lies beyond it, and the stiff cases (eye inside the model, no octree,
// no facets) give bounded answers.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <set>

#include "reconstruct/octree.h"
#include "render/facet_lod.h"
#include "render/facet_selection.h"

namespace s2r {
namespace {

constexpr double kVoxel = 0.002;
constexpr double kRadius = 0.05;

// Eight cameras on a ring at 0.5 m looking at the origin, y down.
ViewCamera ring_camera(double angle_deg, double distance = 0.5, double elevation = 0.1) {
  const double a = angle_deg * std::numbers::pi / 180;
  const Eigen::Vector3d eye(distance * std::sin(a), elevation, distance * std::cos(a));
  const Eigen::Vector3d z = -eye.normalized();
  const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
  ViewCamera v;
  v.K.width = 320, v.K.height = 240, v.K.fx = v.K.fy = 400, v.K.cx = 159.5, v.K.cy = 119.5;
  v.world_from_camera.linear() << x, z.cross(x), z;
  v.world_from_camera.translation() = eye;
  return v;
}

Model sphere_model() {
  Model m;
  m.voxel_size_m = kVoxel;
  for (int c = 0; c < 8; ++c) {
    const ViewCamera v = ring_camera(45.0 * c);
    m.cameras.push_back({v.K, v.world_from_camera, "", c});
  }
  std::vector<SdfSample> samples;
  const int R = int(kRadius / kVoxel) + 4;
  for (int x = -R; x <= R; ++x)
    for (int y = -R; y <= R; ++y)
      for (int z = -R; z <= R; ++z) {
        const Eigen::Vector3d c = Eigen::Vector3d(x, y, z) * kVoxel;
        const double d = c.norm() - kRadius;
        if (std::abs(d) > 3 * kVoxel) continue;
        samples.push_back({{x, y, z}, float(d)});
        if (std::abs(d) > 0.5 * std::sqrt(3.0) * kVoxel) continue;
        FacetRecord f{};
        for (int k = 0; k < 3; ++k) f.center[k] = float(c[k]), f.normal[k] = float(c.normalized()[k]);
        f.size = float(kVoxel);
        f.reliability = 1;
        f.first_camera = uint32_t(m.facet_cameras.size());
        for (uint32_t cam = 0; cam < 8; ++cam)
          if (c.dot(m.cameras[cam].world_from_camera.translation()) > 0) m.facet_cameras.push_back(cam);
        f.camera_count = uint32_t(m.facet_cameras.size()) - f.first_camera;
        m.facets.push_back(f);
      }
  const SurfaceOctree tree = SurfaceOctree::build(samples, kVoxel);
  m.octree = octree_records(tree);
  m.octree_max_level = tree.max_level();
  m.bounds = Eigen::AlignedBox3d(Eigen::Vector3d::Constant(-kRadius - kVoxel), Eigen::Vector3d::Constant(kRadius + kVoxel));
  return m;
}

// A checker of luminance over the sphere, so the luminance test has contrast.
std::vector<float> checker(const Model& m) {
  std::vector<float> lum;
  for (const auto& f : m.facets) lum.push_back((int(std::floor(f.center[0] / 0.02)) + int(std::floor(f.center[1] / 0.02))) % 2 ? 0.8f : 0.2f);
  return lum;
}

LodOptions lod(double t) {
  LodOptions o;
  o.enabled = true;
  o.shape_px = o.luminance = o.texel_px = t;
  return o;
}

TEST(FacetLod, EveryFacetIsInTheTreeAndNodeBillboardsCoverTheirFacets) {
  const Model m = sphere_model();
  ASSERT_GT(m.facets.size(), 1000u);
  const FacetHierarchy h = FacetHierarchy::build(m, checker(m));
  ASSERT_FALSE(h.empty());
  EXPECT_GT(h.node_billboards(), 100u);
  std::vector<uint32_t> out;
  // LOD off: every model facet, in order.
  LodStats st = h.select(ring_camera(10), LodOptions{}, 0.01, out);
  ASSERT_EQ(out.size(), m.facets.size());
  EXPECT_EQ(st.loose_facets, 0u);
  // Every billboard is wide enough for the facets below it: checked through
  // the finest selection a huge threshold cannot refine (the root alone).
  st = h.select(ring_camera(10), lod(1e9), 0.01, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(st.facets_replaced, m.facets.size());
  const FacetRecord& root = h.facets()[out[0]];
  ASSERT_GE(out[0], m.facets.size());
  const Eigen::Vector3f rc(root.center[0], root.center[1], root.center[2]);
  for (const auto& f : m.facets) {
    const float reach = (Eigen::Vector3f(f.center[0], f.center[1], f.center[2]) - rc).norm() + 0.5f * std::sqrt(3.f) * f.size;
    EXPECT_LE(reach, 0.5f * std::sqrt(3.f) * root.size * 1.0001f);
  }
  // The root's cameras are every camera some facet has.
  EXPECT_EQ(root.camera_count, 8u);
}

TEST(FacetLod, NormalConesCullOnlyWhatTheFacetTestWould) {
  const Model m = sphere_model();
  const FacetHierarchy h = FacetHierarchy::build(m, checker(m));
  for (double deg : {0.0, 33.0, 180.0}) {
    const ViewCamera v = ring_camera(deg);
    std::vector<uint32_t> lod_out;
    const LodStats st = h.select(v, lod(1e-9), 0.01, lod_out);  // thresholds nothing passes: leaves only
    EXPECT_EQ(st.node_billboards, 0u);
    EXPECT_GT(st.facets_back_cone, m.facets.size() / 4) << deg;
    const std::set<uint32_t> kept(lod_out.begin(), lod_out.end());
    SelectionOptions so;
    std::vector<FacetInstance> front;
    select_facets(m, v, so, front);
    for (const auto& inst : front) EXPECT_TRUE(kept.count(inst.facet)) << "facet " << inst.facet << " culled at " << deg;
  }
}

TEST(FacetLod, LargerThresholdsDrawFewerBillboards) {
  const Model m = sphere_model();
  const FacetHierarchy h = FacetHierarchy::build(m, checker(m));
  const ViewCamera v = ring_camera(20);
  size_t last = SIZE_MAX;
  for (double t : {1e-9, 0.25, 1.0, 4.0, 16.0, 1e9}) {
    std::vector<uint32_t> out;
    const LodStats st = h.select(v, lod(t), 0.01, out);
    EXPECT_LE(out.size(), last) << t;
    last = out.size();
    // What is drawn plus what stands in for it covers every facet once.
    size_t direct = 0;
    for (uint32_t i : out) direct += i < m.facets.size();
    EXPECT_EQ(direct + st.facets_replaced + st.facets_back_cone + st.facets_outside_frustum, m.facets.size()) << t;
  }
  // Each test refines on its own: contour alone, luminance alone, texel alone.
  for (int which = 0; which < 3; ++which) {
    LodOptions o = lod(1e9);
    (which == 0 ? o.shape_px : which == 1 ? o.luminance : o.texel_px) = 1e-9;
    std::vector<uint32_t> out;
    const LodStats st = h.select(v, o, 0.01, out);
    EXPECT_GT(out.size(), 1u) << which;
    EXPECT_GT(which == 0 ? st.refined_contour : which == 1 ? st.refined_luminance : st.refined_texel, 0u) << which;
  }
}

TEST(FacetLod, VisualFieldLeavesOutWhatLiesBeyondIt) {
  const Model m = sphere_model();
  const FacetHierarchy h = FacetHierarchy::build(m, checker(m));
  const ViewCamera v = ring_camera(0);
  LodOptions o = lod(1e-9);
  o.field = true;  // gaze at the image centre: the sphere is in the central field
  std::vector<uint32_t> centre, away;
  const LodStats a = h.select(v, o, 0.01, centre);
  EXPECT_EQ(a.facets_outside_field, 0u);
  // A gaze far above the image: the sphere lies about 88 deg below it,
  // beyond the field's 70 deg lower edge, so nothing is drawn and everything
  // is counted.
  o.gaze_px = Eigen::Vector2d(v.K.cx, v.K.cy - 40 * v.K.fy);
  const LodStats b = h.select(v, o, 0.01, away);
  EXPECT_TRUE(away.empty());
  EXPECT_EQ(b.facets_outside_field + b.facets_back_cone + b.facets_outside_frustum, m.facets.size());
  EXPECT_GT(b.facets_outside_field, 0u);
  // In the periphery the thresholds loosen: fewer candidates than at the centre.
  LodOptions p = lod(0.5);
  p.field = true;
  std::vector<uint32_t> at_centre, at_edge;
  h.select(v, p, 0.01, at_centre);
  p.gaze_px = Eigen::Vector2d(v.K.cx + 2.5 * v.K.fx, v.K.cy);  // about 68 deg off: the periphery
  const LodStats edge = h.select(v, p, 0.01, at_edge);
  EXPECT_EQ(edge.facets_outside_field, 0u);
  EXPECT_LT(at_edge.size(), at_centre.size());
}

TEST(FacetLod, StiffCases) {
  const Model m = sphere_model();
  const FacetHierarchy h = FacetHierarchy::build(m, checker(m));
  std::vector<uint32_t> out;
  // The eye at the sphere's centre: no node holding it becomes one billboard.
  ViewCamera inside = ring_camera(0, 1e-6, 0);
  const LodStats st = h.select(inside, lod(1e9), 1e-4, out);
  EXPECT_GT(out.size(), 1u);
  for (uint32_t i : out) EXPECT_LT(i, h.facets().size());
  EXPECT_GT(st.nodes_visited, 1u);
  // A model without an octree: every facet is loose and LOD changes nothing.
  Model flat = m;
  flat.octree.clear();
  const FacetHierarchy hf = FacetHierarchy::build(flat);
  EXPECT_TRUE(hf.empty());
  const LodStats sf = hf.select(ring_camera(0), lod(1e9), 0.01, out);
  EXPECT_EQ(out.size(), m.facets.size());
  EXPECT_EQ(sf.loose_facets, m.facets.size());
  // No facets at all.
  Model none = m;
  none.facets.clear();
  none.facet_cameras.clear();
  const FacetHierarchy hn = FacetHierarchy::build(none);
  hn.select(ring_camera(0), lod(1), 0.01, out);
  EXPECT_TRUE(out.empty());
  // Prune: the largest weight is always kept and the rest renormalise.
  float w[4] = {0.7f, 0.26f, 0.04f, 0.f};
  EXPECT_EQ(prune_weights(w, 3, 0.05), 2);
  EXPECT_NEAR(w[0] + w[1], 1.f, 1e-6f);
  EXPECT_EQ(w[2], 0.f);
  float single[1] = {1.f};
  EXPECT_EQ(prune_weights(single, 1, 0.9), 1);
}

}  // namespace
}  // namespace s2r
