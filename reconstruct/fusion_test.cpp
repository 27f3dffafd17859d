// Fusion, facets and the error bound on analytic scenes (a sphere seen by a
// ring of exact depth cameras), and the stiff cases (docs/testing.md):
// a view with no valid depth, one camera only, a facet no camera sees, w of
// the whole object, a voxel at the volume's border.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <numbers>
#include <optional>
#include <random>
#include <unistd.h>

#include "core/image_io.h"
#include "reconstruct/camera_depth.h"
#include "reconstruct/fusion.h"
#include "reconstruct/mask_windows.h"
#include "reconstruct/microfacets.h"
#include "reconstruct/ring_scene_test.h"

using namespace s2r;
using namespace s2r::ring_scene;
namespace fs = std::filesystem;

namespace {

// Exact depth (z, 0.1 mm units) of the sphere.
ImageU16 sphere_depth(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera) {
  ImageU16 d(K.width, K.height, 1, 0);
  const Eigen::Vector3d c = world_from_camera.inverse() * kCentre;
  for (int y = 0; y < K.height; ++y)
    for (int x = 0; x < K.width; ++x) {
      const Eigen::Vector3d r = K.ray({double(x), double(y)})->normalized();
      const double b = r.dot(c), disc = b * b - (c.squaredNorm() - kRadius * kRadius);
      if (disc < 0) continue;
      const double t = b - std::sqrt(disc);
      d.at(x, y) = uint16_t(std::lround(t * r.z() / 1e-4));
    }
  return d;
}

struct Ring {
  std::vector<ImageU16> depth;
  std::vector<Eigen::Isometry3d> poses;
};
Ring ring(int n) {
  Ring r;
  for (int i = 0; i < n; ++i) {
    r.poses.push_back(ring_pose(360.0 * i / n));
    r.depth.push_back(sphere_depth(camera(), r.poses.back()));
  }
  return r;
}

DepthObservation obs(const Ring& r, size_t i) { return {&r.depth[i], 1e-4, camera(), r.poses[i]}; }

}  // namespace

TEST(VoxelChoice, GivenBoundPixelLimitsAndExtent) {
  VoxelRequest r;
  r.target_error_px = 0.5;
  r.focal_px = 600;
  r.near_distance_m = 0.4;
  r.delta_rad = 7.5 * kDeg;
  r.pixel_m = 0.4 / 600;
  r.extent_m = 0.3;
  // Given: used as it is; per-region sizes reach twice it.
  r.given_m = 0.003;
  VoxelChoice c = choose_voxel(r);
  EXPECT_FALSE(c.automatic);
  EXPECT_EQ(c.base_m, 0.003);
  EXPECT_EQ(c.coarse_m, 0.006);
  EXPECT_TRUE(c.warnings.empty());
  // Automatic: half the bound for per-region sizes, the bound itself as the coarse size.
  r.given_m.reset();
  c = choose_voxel(r);
  const double bound = voxel_for_error(0.5, 600, 0.4, 7.5 * kDeg);
  ASSERT_LT(bound, 8 * r.pixel_m);
  EXPECT_TRUE(c.automatic);
  EXPECT_FALSE(c.limited_by_pixels);
  EXPECT_DOUBLE_EQ(c.bound_m, bound);
  EXPECT_DOUBLE_EQ(c.base_m, bound / 2);
  EXPECT_DOUBLE_EQ(c.coarse_m, bound);
  // Cameras 0.5 deg apart: the bound would allow huge facets; 8 input pixels hold it.
  r.delta_rad = 0.25 * kDeg;
  c = choose_voxel(r);
  EXPECT_TRUE(c.limited_by_pixels);
  EXPECT_DOUBLE_EQ(c.bound_m, 8 * r.pixel_m);
  // A tiny target error: no finer than two input pixels, with a warning.
  r.delta_rad = 7.5 * kDeg;
  r.target_error_px = 0.01;
  c = choose_voxel(r);
  EXPECT_DOUBLE_EQ(c.base_m, 2 * r.pixel_m);
  EXPECT_EQ(c.warnings.size(), 1u);
  // A small object: at most a quarter of its extent.
  r.target_error_px = 0.5;
  r.extent_m = 0.004;
  c = choose_voxel(r);
  EXPECT_DOUBLE_EQ(c.base_m, 0.001);
  // A given voxel below an input pixel is kept, with a warning.
  r.given_m = 0.1 * r.pixel_m;
  c = choose_voxel(r);
  EXPECT_DOUBLE_EQ(c.base_m, 0.1 * r.pixel_m);
  EXPECT_EQ(c.warnings.size(), 1u);
}

TEST(ErrorBound, SeedExampleAndInverse) {
  // 30 deg between cameras: a view is at most 15 deg from the nearest one.
  EXPECT_NEAR(texel_error_bound(1.0, 15 * kDeg), 0.129, 0.001);
  const double w = voxel_for_error(0.5, 600, 0.4, 7.5 * kDeg);
  EXPECT_NEAR(600 * texel_error_bound(w, 7.5 * kDeg) / 0.4, 0.5, 1e-9);
  // Grazing / coincident extremes stay finite.
  EXPECT_TRUE(std::isfinite(voxel_for_error(0.5, 600, 0.4, 0)));
  EXPECT_NEAR(texel_error_bound(1.0, 3.0), 0.5, 1e-12);  // clamped at 90 deg
}

TEST(CameraSpacing, RingAndLoneCamera) {
  std::vector<Eigen::Isometry3d> cams;
  for (int i = 0; i < 24; ++i) cams.push_back(ring_pose(15.0 * i, 0));
  const CameraSpacing s = camera_spacing(cams, kCentre);
  EXPECT_NEAR(s.max_gap_rad / kDeg, 15, 1e-6);
  EXPECT_NEAR(s.median_distance_m, 0.3, 1e-9);
  EXPECT_LT((optical_axes_centre(cams) - kCentre).norm(), 1e-9);
  const CameraSpacing one = camera_spacing({cams[0]}, kCentre);
  EXPECT_NEAR(one.max_gap_rad, std::numbers::pi, 1e-12);  // any view may be opposite
}

TEST(Reliability, AgreementAndViewCount) {
  EXPECT_EQ(depth_reliability(1, 0, 1e-3), 0.f);
  EXPECT_FLOAT_EQ(depth_reliability(4, 0, 1e-3), 1.f);
  EXPECT_NEAR(depth_reliability(4, 1e-3f, 1e-3), std::exp(-0.5), 1e-6);
  EXPECT_LT(depth_reliability(2, 0, 1e-3), depth_reliability(3, 0, 1e-3));
  EXPECT_EQ(depth_reliability(5, std::nanf(""), 1e-3), 0.f);
}

TEST(BackdropMask, UniformBorderAndClutter) {
  ImageU8 im(64, 48, 3, 50);
  for (int y = 10; y < 30; ++y)
    for (int x = 20; x < 40; ++x) im.at(x, y, 1) = 200;
  auto m = backdrop_mask(im);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->at(30, 20), 255);
  EXPECT_EQ(m->at(5, 5), 0);
  for (int y = 0; y < 48; ++y)  // a room behind the object: the border varies
    for (int x = 0; x < 64; ++x) im.at(x, y, 0) = uint8_t((x * 37 + y * 91) % 256);
  double spread = 0;
  EXPECT_FALSE(backdrop_mask(im, 0, &spread));
  EXPECT_GT(spread, 12);
}

TEST(Fusion, SphereFromARingOfExactDepth) {
  const Ring r = ring(12);
  const double w = 0.004;
  SparseVolume vol(w, 4 * w);
  for (size_t i = 0; i < r.depth.size(); ++i) vol.integrate(obs(r, i));
  EXPECT_EQ(vol.fusion_stats().views, 12u);
  const auto ev = vol.evidence(w / 2);
  ASSERT_GT(ev.size(), 500u);
  size_t within = 0, outward = 0, reliable = 0;
  for (const auto& e : ev) {
    const Eigen::Vector3d c = e.centre.cast<double>();
    within += std::abs((c - kCentre).norm() - kRadius) <= w;
    outward += e.normal.cast<double>().dot((c - kCentre).normalized()) > 0.9;
    reliable += e.reliability > 0.5;
    EXPECT_FALSE(e.fuzzy);
  }
  EXPECT_GE(double(within) / ev.size(), 0.99);
  EXPECT_GE(double(outward) / ev.size(), 0.95);
  EXPECT_GE(double(reliable) / ev.size(), 0.5);
  // The fused surface, ray cast from a camera, gives the sphere's distance.
  auto caster = MeshRaycaster::create(vol.surface_mesh(ev));
  ASSERT_TRUE(caster);
  const ImageF d = (*caster)->distance_image(camera(), r.poses[0]);
  const Eigen::Vector3d eye = r.poses[0].translation();
  EXPECT_NEAR(d.at(80, 60), (kCentre - eye).norm() - kRadius, w / 4);
  EXPECT_EQ(d.at(0, 0), 0.f);  // misses
  EXPECT_GT(vol.memory_bytes(), 0u);
  // The fused surface is wound with its normals inward: leaving out the faces
  // turned away from the camera changes (almost) no pixel.
  const Mesh surface = vol.surface_mesh(ev);
  const MeshRasterizer both(surface), front(surface, MeshRasterizer::Faces::kInwardWound);
  for (size_t i = 0; i < r.poses.size(); i += 4) {
    MeshRasterizer::Stats st;
    const ImageF a = both.distance_image(camera(), r.poses[i]), b = front.distance_image(camera(), r.poses[i], &st);
    size_t hits = 0, same = 0;
    for (size_t p = 0; p < a.data.size(); ++p)
      if (a.data[p] > 0) ++hits, same += a.data[p] == b.data[p];
    EXPECT_GT(hits, 1000u);
    EXPECT_GE(double(same) / double(hits), 0.999) << "camera " << i;
    EXPECT_GT(st.back_faces, surface.faces.size() / 3) << "camera " << i;
  }
}

TEST(Fusion, ViewsTogetherEqualViewsOneByOne) {
  // One pass over all views gives the same numbers as integrating them one
  // after the other, a view without depth included.
  const Ring r = ring(8);
  const double w = 0.003;
  const ImageU16 zeros(camera().width, camera().height, 1, 0);
  SparseVolume one(w, 4 * w), all(w, 4 * w);
  std::vector<DepthObservation> views;
  for (size_t i = 0; i < r.depth.size(); ++i) {
    views.push_back(obs(r, i));
    if (i == 3) views.push_back({&zeros, 1e-4, camera(), r.poses[0]});
  }
  for (const auto& v : views) one.integrate(v);
  int ticks = 0;
  all.integrate(views, 2, [&] { ++ticks; });
  EXPECT_EQ(ticks, int(views.size()));
  EXPECT_EQ(one.fusion_stats().views, all.fusion_stats().views);
  EXPECT_EQ(all.fusion_stats().views_without_depth, 1u);
  EXPECT_EQ(one.fusion_stats().voxel_updates, all.fusion_stats().voxel_updates);
  EXPECT_EQ(one.fusion_stats().depth_samples, all.fusion_stats().depth_samples);
  EXPECT_EQ(one.active_voxels(), all.active_voxels());
  const auto a = one.samples(), b = all.samples();
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].first, b[i].first);
    ASSERT_EQ(a[i].second, b[i].second);  // bit for bit
  }
  const auto ea = one.evidence(w / 2), eb = all.evidence(w / 2);
  ASSERT_EQ(ea.size(), eb.size());
  for (size_t i = 0; i < ea.size(); ++i) ASSERT_EQ(ea[i].spread_m, eb[i].spread_m);
}

TEST(Fusion, ViewWithoutValidDepthChangesNothing) {
  const Ring r = ring(6);
  SparseVolume a(0.004, 0.016), b(0.004, 0.016);
  ImageU16 zeros(camera().width, camera().height, 1, 0);
  for (size_t i = 0; i < 6; ++i) a.integrate(obs(r, i)), b.integrate(obs(r, i));
  b.integrate({&zeros, 1e-4, camera(), r.poses[0]});
  EXPECT_EQ(b.fusion_stats().views_without_depth, 1u);
  EXPECT_EQ(a.evidence(0.001).size(), b.evidence(0.001).size());
}

TEST(Fusion, OneCameraOnlyGivesUnreliableFacets) {
  const Ring r = ring(12);
  SparseVolume vol(0.004, 0.016);
  vol.integrate(obs(r, 0));
  const auto ev = vol.evidence(0.001);
  ASSERT_GT(ev.size(), 50u);
  for (const auto& e : ev) EXPECT_EQ(e.reliability, 0.f);  // no agreement to measure
  // Per region they merge into facets twice the voxel.
  std::vector<FacetRecord> facets;
  std::vector<uint32_t> cams;
  FacetOptions fo;
  fo.voxel_m = 0.004;
  const FacetStats st = build_facets(ev, {{camera(), r.poses[0], nullptr}}, fo, facets, cams);
  EXPECT_EQ(st.fine, 0u);
  EXPECT_GT(st.coarse, 0u);
  for (const auto& f : facets) EXPECT_FLOAT_EQ(f.size, 0.008f);
}

TEST(Fusion, CropAtTheVolumeBorder) {
  const Ring r = ring(12);
  // The crop cuts the sphere through its centre: nothing beyond it, no crash at the border.
  const Eigen::AlignedBox3d crop(kCentre - Eigen::Vector3d(1, 1, 1), kCentre + Eigen::Vector3d(0, 1, 1));
  SparseVolume vol(0.004, 0.016, crop);
  for (size_t i = 0; i < r.depth.size(); ++i) vol.integrate(obs(r, i));
  EXPECT_GT(vol.fusion_stats().samples_outside_crop, 0u);
  const auto ev = vol.evidence(0.001);
  ASSERT_FALSE(ev.empty());
  for (const auto& e : ev) EXPECT_LE(e.centre.x(), kCentre.x() + 1e-6);
}

TEST(Fusion, VoxelAsLargeAsTheObject) {
  const Ring r = ring(12);
  SparseVolume vol(2 * kRadius, 4 * kRadius);
  for (size_t i = 0; i < r.depth.size(); ++i) vol.integrate(obs(r, i));
  const auto ev = vol.evidence(kRadius);
  ASSERT_FALSE(ev.empty());
  for (const auto& e : ev) {
    EXPECT_TRUE(e.centre.allFinite());
    EXPECT_LE(((e.centre.cast<double>() - kCentre).norm()), 2 * kRadius * 1.8);
  }
}

TEST(VisualHull, SphereSilhouettesAndDepthCarving) {
  const Ring r = ring(12);
  std::vector<ImageU8> masks;
  for (const auto& d : r.depth) {
    ImageU8 m(d.width, d.height, 1, 0);
    for (size_t i = 0; i < d.pixels(); ++i) m.data[i] = d.data[i] ? 255 : 0;
    masks.push_back(m);
  }
  std::vector<SilhouetteObservation> sil;
  for (size_t i = 0; i < masks.size(); ++i) sil.push_back({&masks[i], camera(), r.poses[i]});
  const double w = 0.004;
  const Eigen::AlignedBox3d box(kCentre - Eigen::Vector3d::Constant(0.1), kCentre + Eigen::Vector3d::Constant(0.1));
  // Silhouettes only: the hull's boundary, a little outside the sphere.
  SparseVolume hull(w, 4 * w);
  const HullStats hs = hull.carve_hull(sil, {}, box);
  EXPECT_GT(hs.hull_voxels, 5000u);
  const auto ev = hull.evidence(w);
  ASSERT_GT(ev.size(), 500u);
  for (const auto& e : ev) {
    EXPECT_TRUE(e.fuzzy);
    const double dist = (e.centre.cast<double>() - kCentre).norm() - kRadius;
    EXPECT_GT(dist, -1.5 * w);
    EXPECT_LT(dist, 0.02);  // a ring of 12 leaves the poles loose
  }
  // With depth as well, depth explains everything: (almost) no fuzzy voxel is left.
  SparseVolume both(w, 4 * w);
  std::vector<DepthObservation> d;
  for (size_t i = 0; i < r.depth.size(); ++i) both.integrate(obs(r, i)), d.push_back(obs(r, i));
  const HullStats bs = both.carve_hull(sil, d, box);
  EXPECT_GT(bs.solid_by_depth, 1000u);
  EXPECT_LT(bs.fuzzy_voxels, bs.hull_voxels / 20);
}

namespace {

// A cube with a square pit in its top face (the -y side, where the cameras
// are): the distance along a ray into it, 0 where it misses.
constexpr double kHalf = 0.04, kPitHalf = 0.02, kPitDepth = 0.03;
bool in_pit(const Eigen::Vector3d& p) {
  const Eigen::Vector3d q = p - kCentre;
  return std::abs(q.x()) < kPitHalf && std::abs(q.z()) < kPitHalf && q.y() < -kHalf + kPitDepth;
}
// Entry and exit of a ray into an axis-aligned box about kCentre.
std::optional<std::pair<double, double>> slab(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& lo,
                                              const Eigen::Vector3d& hi) {
  double t0 = 0, t1 = 1e9;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) {
      if (o[a] < lo[a] || o[a] > hi[a]) return std::nullopt;
      continue;
    }
    double u = (lo[a] - o[a]) / d[a], v = (hi[a] - o[a]) / d[a];
    if (u > v) std::swap(u, v);
    t0 = std::max(t0, u), t1 = std::min(t1, v);
  }
  if (t0 > t1) return std::nullopt;
  return std::make_pair(t0, t1);
}
ImageU16 pit_depth(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera) {
  ImageU16 out(K.width, K.height, 1, 0);
  const Eigen::Vector3d h(kHalf, kHalf, kHalf);
  const Eigen::Vector3d pit_lo = kCentre + Eigen::Vector3d(-kPitHalf, -kHalf - 0.01, -kPitHalf),
                        pit_hi = kCentre + Eigen::Vector3d(kPitHalf, -kHalf + kPitDepth, kPitHalf);
  const Eigen::Vector3d o = world_from_camera.translation();
  for (int y = 0; y < K.height; ++y)
    for (int x = 0; x < K.width; ++x) {
      const Eigen::Vector3d rc = K.ray({double(x), double(y)})->normalized();
      const Eigen::Vector3d d = world_from_camera.linear() * rc;
      auto b = slab(o, d, kCentre - h, kCentre + h);
      if (!b) continue;
      double t = b->first;
      if (auto p = slab(o, d, pit_lo, pit_hi); p && p->first <= t + 1e-12 && t < p->second) t = p->second;
      if (t >= b->second) continue;  // through the pit and out
      out.at(x, y) = uint16_t(std::lround(t * rc.z() / 1e-4));
    }
  return out;
}

}  // namespace

// Depth that comes after the hull (photo-consistency's): no silhouette shows
// a pit in a cube's top face, so the hull fills it; the same cameras' depth
// shows it empty and carves it where two of them agree, and nothing of the
// cube goes. One camera alone carves nothing.
TEST(VisualHull, CarveFreeByDepthAfterTheHull) {
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < 12; ++i) poses.push_back(ring_pose(30.0 * i, 10));
  for (int i = 0; i < 8; ++i) poses.push_back(ring_pose(45.0 * i + 20, 55));
  std::vector<ImageU16> depth;
  std::vector<ImageU8> masks;
  for (const auto& T : poses) {
    depth.push_back(pit_depth(camera(), T));
    ImageU8 m(camera().width, camera().height, 1, 0);
    for (size_t i = 0; i < m.pixels(); ++i) m.data[i] = depth.back().data[i] ? 255 : 0;
    masks.push_back(std::move(m));
  }
  std::vector<SilhouetteObservation> sil;
  std::vector<DepthObservation> d;
  for (size_t i = 0; i < poses.size(); ++i) {
    sil.push_back({&masks[i], camera(), poses[i]});
    d.push_back({&depth[i], 1e-4, camera(), poses[i]});
  }
  const double w = 0.002;
  const Eigen::AlignedBox3d box(kCentre - Eigen::Vector3d::Constant(0.06), kCentre + Eigen::Vector3d::Constant(0.06));
  // Hull voxels in the pit (by a voxel's margin), and in the cube off the pit.
  auto count = [&](const SparseVolume& v) {
    std::pair<size_t, size_t> n{0, 0};
    for (const auto& c : v.fit_candidates(0)) {
      const Eigen::Vector3d p = c.cast<double>(), q = p - kCentre;
      const bool pit = std::abs(q.x()) < kPitHalf - w && std::abs(q.z()) < kPitHalf - w && q.y() < -kHalf + kPitDepth - w;
      const bool solid = (q.cwiseAbs().array() < kHalf - w).all() && !in_pit(p) &&
                         !(std::abs(q.x()) < kPitHalf + w && std::abs(q.z()) < kPitHalf + w && q.y() < -kHalf + kPitDepth + w);
      n.first += pit, n.second += solid;
    }
    return n;
  };
  SparseVolume one(w, 2 * w);
  one.carve_hull(sil, {}, box);
  const auto before = count(one);
  EXPECT_GT(before.first, 1000u) << "the hull fills the pit";
  EXPECT_EQ(one.carve_free({d[12]}, 2, 2 * w), 0u) << "one view never carves when two are asked for";

  SparseVolume two(w, 2 * w);
  two.carve_hull(sil, {}, box);
  const size_t carved = two.carve_free(d, 2, 2 * w);
  const auto after = count(two);
  // Not all: within the truncation distance of the floor, and where a
  // voxel's footprint takes in the rim, no view shows it empty.
  EXPECT_GE(carved, before.first / 2);
  EXPECT_LT(after.first, before.first / 2) << "most of the pit is carved";
  EXPECT_EQ(after.second, before.second) << "nothing of the cube is carved";
  for (const auto& e : two.evidence(w)) EXPECT_TRUE(e.fuzzy);
}

TEST(Facets, OccludedCameraAndUnseenFacet) {
  // Two facets on the z axis; a camera at the origin looking along +z sees the
  // near one; the far one is behind the near surface (distance image says 1 m).
  Intrinsics K = camera();
  ImageF dist(K.width, K.height, 1, 1.0f);
  std::vector<EvidenceVoxel> ev(2);
  ev[0].ijk = {0, 0, 100}, ev[0].centre = {0, 0, 1.0f}, ev[0].reliability = 1;
  ev[1].ijk = {0, 0, 150}, ev[1].centre = {0, 0, 1.5f}, ev[1].reliability = 1;
  FacetOptions fo;
  fo.voxel_m = 0.01;
  std::vector<FacetRecord> facets;
  std::vector<uint32_t> cams;
  FacetStats st = build_facets(ev, {{K, Eigen::Isometry3d::Identity(), &dist}}, fo, facets, cams);
  EXPECT_EQ(st.unseen, 1u);
  EXPECT_EQ(st.occluded, 1u);
  ASSERT_EQ(facets.size(), 1u);  // the unseen one is left out
  EXPECT_FLOAT_EQ(facets[0].center[2], 1.0f);
  EXPECT_EQ(facets[0].camera_count, 1u);
  fo.keep_unseen = true;
  st = build_facets(ev, {{K, Eigen::Isometry3d::Identity(), &dist}}, fo, facets, cams);
  ASSERT_EQ(facets.size(), 2u);
  EXPECT_EQ(facets[1].camera_count, 0u);
}

TEST(Facets, VisibilityGridReadFromWholeOrGridDepthAlike) {
  // Depth in blocks of 5 x 5 pixels, occluding (1 m) or empty (0) in turn;
  // facets at 1.5 m all over the view. With a stride the test reads the same
  // grid points from the whole image as from the grid's own image.
  const Intrinsics K = camera();
  ImageF whole(K.width, K.height, 1, 0.f);
  for (int y = 0; y < K.height; ++y)
    for (int x = 0; x < K.width; ++x) whole.at(x, y) = (x / 5 + y / 5) % 2 ? 1.f : 0.f;
  std::vector<EvidenceVoxel> ev;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 30; ++j) {
      EvidenceVoxel e;
      e.ijk = {i, j, 0};
      const Eigen::Vector3d ray = *K.ray({(i + 0.37) * K.width / 40.0, (j + 0.61) * K.height / 30.0});
      e.centre = (1.5 * ray).cast<float>(), e.reliability = 1;
      ev.push_back(e);
    }
  FacetOptions fo;
  fo.voxel_m = 0.001;
  fo.keep_unseen = true;
  for (int k : {1, 2, 3}) {
    const Intrinsics G = visibility_grid(K, k);
    ImageF grid(G.width, G.height, 1, 0.f);
    for (int gy = 0; gy < G.height; ++gy)
      for (int gx = 0; gx < G.width; ++gx) grid.at(gx, gy) = whole.at(k * gx + (k - 1) / 2, k * gy + (k - 1) / 2);
    std::vector<FacetRecord> fa, fb;
    std::vector<uint32_t> ca, cb;
    const FacetStats sa = build_facets(ev, {{K, Eigen::Isometry3d::Identity(), &whole, {}, k}}, fo, fa, ca);
    const FacetStats sb = build_facets(ev, {{K, Eigen::Isometry3d::Identity(), &grid, {}, k}}, fo, fb, cb);
    EXPECT_GT(sa.occluded, 300u) << k;
    EXPECT_GT(sa.camera_links, 300u) << k;
    EXPECT_EQ(sa.occluded, sb.occluded) << k;
    ASSERT_EQ(fa.size(), fb.size());
    for (size_t i = 0; i < fa.size(); ++i) ASSERT_EQ(fa[i].camera_count, fb[i].camera_count) << k << " " << i;
  }
}

TEST(CameraTexture, RgbazRoundTrip) {
  const fs::path p = fs::temp_directory_path() / ("s2r_rgbaz_" + std::to_string(::getpid()) + ".exr");
  RgbazImage t{ImageU8(8, 4, 4, 0), ImageF(8, 4, 1, 0.f)};
  for (size_t i = 0; i < t.rgba.data.size(); ++i) t.rgba.data[i] = uint8_t(i * 7);
  for (size_t i = 0; i < t.distance.data.size(); ++i) t.distance.data[i] = 0.25f + 1e-4f * float(i);
  ASSERT_TRUE(write_rgbaz(p, t));
  auto back = read_rgbaz(p);
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_EQ(back->rgba.data, t.rgba.data);  // 8-bit levels survive half floats
  EXPECT_EQ(back->distance.data, t.distance.data);  // distances are stored as float
  EXPECT_FALSE(write_rgbaz(p, {ImageU8(8, 4, 3), ImageF(8, 4, 1)}));
  fs::remove(p);
}

// The hull's window tests (any foreground; only foreground) against reading
// every pixel: sparse and dense
// masks of sizes that are and are not multiples of the block, windows
// inside, across the edges, wholly outside, one pixel and the whole image,
// a mask of three channels (its first read).
TEST(MaskWindows, AnswersAsReadingEveryPixelDoes) {
  std::mt19937 gen(5);
  for (const auto& [w, h, ch, density] : std::vector<std::tuple<int, int, int, double>>{
           {37, 29, 1, 0.002}, {64, 48, 1, 0.02}, {33, 17, 3, 0.2}, {8, 5, 1, 0.05}, {1, 1, 1, 1.0}, {41, 23, 1, 0.995}}) {
    ImageU8 m(w, h, ch);
    std::bernoulli_distribution fg(density);
    for (size_t p = 0; p < m.pixels(); ++p) m.data[p * size_t(ch)] = fg(gen) ? uint8_t(1 + gen() % 255) : 0;
    m.at(w / 2, h / 2, 0) = 7;  // at least one
    if (ch == 3) {  // other channels set where the first is not: they must not count
      for (size_t p = 0; p < m.pixels(); ++p) m.data[p * 3 + 1] = 255;
    }
    const MaskWindows t(m);
    auto brute_all = [&](int x0, int y0, int x1, int y1) {
      if (x0 < 0 || y0 < 0 || x1 >= w || y1 >= h || x0 > x1 || y0 > y1) return false;
      for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x)
          if (!m.at(x, y, 0)) return false;
      return true;
    };
    auto brute = [&](int x0, int y0, int x1, int y1) {
      for (int y = std::max(y0, 0); y <= std::min(y1, h - 1); ++y)
        for (int x = std::max(x0, 0); x <= std::min(x1, w - 1); ++x)
          if (m.at(x, y, 0)) return true;
      return false;
    };
    std::uniform_int_distribution<int> cx(-6, w + 5), cy(-6, h + 5);
    int found = 0, all_found = 0;
    for (int k = 0; k < 20000; ++k) {
      int x0 = cx(gen), x1 = cx(gen), y0 = cy(gen), y1 = cy(gen);
      if (k % 3 == 0) x1 = x0 + int(gen() % 3), y1 = y0 + int(gen() % 3);  // small windows, as the finest cells'
      const bool want = brute(x0, y0, x1, y1);
      found += want;
      ASSERT_EQ(t.any(x0, y0, x1, y1), want) << w << "x" << h << " [" << x0 << "," << x1 << "] x [" << y0 << "," << y1 << "]";
      const bool full = brute_all(x0, y0, x1, y1);
      all_found += full;
      ASSERT_EQ(t.all(x0, y0, x1, y1), full) << w << "x" << h << " [" << x0 << "," << x1 << "] x [" << y0 << "," << y1 << "]";
    }
    EXPECT_EQ(t.any(0, 0, w - 1, h - 1), brute(0, 0, w - 1, h - 1));
    EXPECT_FALSE(t.any(w, 0, w + 3, h - 1));
    if (density < 1) {
      EXPECT_GT(20000 - found, 0);  // some windows were empty
    }
    EXPECT_GT(found, 0);
    if (density > 0.1) {
      EXPECT_GT(all_found, 0);  // some windows were all foreground
    }
  }
}
