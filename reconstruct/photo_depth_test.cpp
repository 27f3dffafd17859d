// Per-camera depth by photo-consistency on an analytic scene: a sphere with a
// solid noise texture seen by a ring of cameras, the hull given as a larger
// sphere (a loose hull, as silhouettes leave in a concavity), the surface
// itself, or a sphere of one flat colour.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <numbers>

#include "reconstruct/photo_depth.h"
#include "reconstruct/ring_scene_test.h"

using namespace s2r;
using namespace s2r::ring_scene;

namespace {

// Value noise on a 3-mm lattice, trilinear: a texture fixed to the surface.
double noise(const Eigen::Vector3d& p) {
  const Eigen::Vector3d q = p / 0.003;
  const Eigen::Vector3d f = q.array().floor();
  const Eigen::Vector3d t = q - f;
  auto lattice = [](int64_t x, int64_t y, int64_t z) {
    uint64_t h = uint64_t(x) * 0x9E3779B97F4A7C15ull ^ uint64_t(y) * 0xC2B2AE3D27D4EB4Full ^ uint64_t(z) * 0x165667B19E3779F9ull;
    h ^= h >> 29, h *= 0xBF58476D1CE4E5B9ull, h ^= h >> 32;
    return double(h & 0xffff) / 65535.0;
  };
  double v = 0;
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
    const double w = (dx ? t.x() : 1 - t.x()) * (dy ? t.y() : 1 - t.y()) * (dz ? t.z() : 1 - t.z());
    v += w * lattice(int64_t(f.x()) + dx, int64_t(f.y()) + dy, int64_t(f.z()) + dz);
  }
  return v;
}

// Distance along each pixel's ray to a sphere about kCentre, 0 where it misses.
ImageF sphere_distance(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, double radius) {
  ImageF d(K.width, K.height, 1, 0.0f);
  const Eigen::Vector3d c = world_from_camera.inverse() * kCentre;
  for (int y = 0; y < K.height; ++y)
    for (int x = 0; x < K.width; ++x) {
      const Eigen::Vector3d r = K.ray({double(x), double(y)})->normalized();
      const double b = r.dot(c), disc = b * b - (c.squaredNorm() - radius * radius);
      if (disc >= 0) d.at(x, y) = float(b - std::sqrt(disc));
    }
  return d;
}

struct Scene {
  std::vector<ImageU8> colour, mask;
  std::vector<PhotoView> views;
};

// Cameras at the given angles on the ring; the sphere textured (or flat).
Scene render(const std::vector<double>& angles, bool textured) {
  Scene s;
  const Intrinsics K = camera();
  for (double a : angles) {
    const Eigen::Isometry3d T = ring_pose(a);
    const ImageF d = sphere_distance(K, T, kRadius);
    ImageU8 c(K.width, K.height, 3, 0), m(K.width, K.height, 1, 0);
    for (int y = 0; y < K.height; ++y)
      for (int x = 0; x < K.width; ++x) {
        if (!(d.at(x, y) > 0)) continue;
        const Eigen::Vector3d p = T * (K.ray({double(x), double(y)})->normalized() * d.at(x, y));
        const uint8_t v = uint8_t(std::lround(textured ? 40 + 180 * noise(p) : 128));
        c.at(x, y, 0) = c.at(x, y, 1) = c.at(x, y, 2) = v;
        m.at(x, y) = 255;
      }
    s.colour.push_back(std::move(c));
    s.mask.push_back(std::move(m));
  }
  for (size_t i = 0; i < angles.size(); ++i) s.views.push_back({&s.colour[i], &s.mask[i], K, ring_pose(angles[i])});
  return s;
}

PhotoDepthParams params() {
  PhotoDepthParams p;
  p.step_m = 0.001;
  p.range_m = 0.03;
  return p;
}

}  // namespace

TEST(PhotoDepth, NeighboursNearestInDirection) {
  const Scene s = render({0, 15, -15, 30, -30, 90, 180}, true);
  const auto n = photo_neighbours(s.views, 0, kCentre, params());
  ASSERT_EQ(n.size(), 4u);  // 90 and 180 degrees are past max_angle_deg
  EXPECT_TRUE((n[0] == 1 && n[1] == 2) || (n[0] == 2 && n[1] == 1));
  EXPECT_TRUE((n[2] == 3 && n[3] == 4) || (n[2] == 4 && n[3] == 3));
}

// A hull 12 mm outside the surface: the search finds the surface behind it.
TEST(PhotoDepth, FindsTheSurfaceBehindALooseHull) {
  const Scene s = render({0, 15, -15, 30, -30}, true);
  const PhotoDepthParams p = params();
  const ImageF hull = sphere_distance(camera(), s.views[0].world_from_camera, kRadius + 0.012);
  const ImageF truth = sphere_distance(camera(), s.views[0].world_from_camera, kRadius);
  PhotoDepthStats st;
  const ImageF d = photo_consistent_depth(s.views, 0, {1, 2, 3, 4}, hull, p, &st);
  size_t inner = 0, found = 0, kept = 0, close = 0, deep = 0;
  for (int y = 0; y < truth.height; ++y)
    for (int x = 0; x < truth.width; ++x) {
      const float t = truth.at(x, y), v = d.at(x, y);
      if (v > 0) {
        ++kept;
        EXPECT_GE(v, hull.at(x, y)) << "never in front of the hull";
        if (t > 0 && std::abs(v - t) <= 2 * p.step_m) ++close;
        // Deeper than the surface by the carving margin (the job carves
        // what lies in front by the truncation distance, 4 w) is what would
        // cut into the object: rare, and never by much.
        if (t > 0 && v - t > 3 * p.step_m) ++deep;
        if (t > 0) {
          EXPECT_LE(v - t, 6 * p.step_m) << x << "," << y;
        }
      }
      // Well inside the silhouette, where the sphere faces the camera.
      const Eigen::Vector3d r = camera().ray({double(x), double(y)})->normalized();
      if (t > 0 && (s.views[0].world_from_camera * (r * t) - kCentre).normalized().dot(-(s.views[0].world_from_camera.linear() * r)) > 0.6) {
        ++inner;
        if (v > 0 && std::abs(v - t) <= 2 * p.step_m) ++found;
      }
    }
  ASSERT_GT(inner, 1000u);
  EXPECT_GT(double(found) / double(inner), 0.8) << found << " of " << inner;
  // The rest within a few steps, or at the hull (confirming it: carves nothing).
  EXPECT_GT(double(close) / double(kept), 0.85) << close << " of " << kept;
  EXPECT_LT(double(deep) / double(kept), 0.01) << deep << " of " << kept;
  EXPECT_GT(st.pixels_behind_hull, inner / 2);
  EXPECT_EQ(st.neighbours_used, 4);
}

// The hull on the surface: the search confirms it and moves nothing deeper.
TEST(PhotoDepth, HullOnTheSurfaceStays) {
  const Scene s = render({0, 15, -15, 30, -30}, true);
  const ImageF hull = sphere_distance(camera(), s.views[0].world_from_camera, kRadius);
  PhotoDepthStats st;
  photo_consistent_depth(s.views, 0, {1, 2, 3, 4}, hull, params(), &st);
  EXPECT_GT(st.pixels_at_hull, (st.pixels_on_hull - st.pixels_at_silhouette) / 2);
  EXPECT_LT(st.pixels_behind_hull, st.pixels_on_hull / 50);
}

// Stiff cases: a flat colour matches everywhere and nowhere (nothing kept);
// one neighbour is not enough to vote (nothing kept).
TEST(PhotoDepth, FlatColourOrOneNeighbourKeepsNothing) {
  const Scene flat = render({0, 15, -15, 30, -30}, false);
  const ImageF hull = sphere_distance(camera(), flat.views[0].world_from_camera, kRadius + 0.012);
  PhotoDepthStats st;
  const ImageF d = photo_consistent_depth(flat.views, 0, {1, 2, 3, 4}, hull, params(), &st);
  for (float v : d.data) EXPECT_EQ(v, 0.0f);
  EXPECT_EQ(st.pixels_untextured + st.pixels_at_silhouette + st.pixels_unmatched + st.pixels_ambiguous, st.pixels_on_hull);

  const Scene s = render({0, 15}, true);
  PhotoDepthStats one;
  const ImageF e = photo_consistent_depth(s.views, 0, {1}, hull, params(), &one);
  for (float v : e.data) EXPECT_EQ(v, 0.0f);
  EXPECT_EQ(one.pixels_unmatched + one.pixels_at_silhouette + one.pixels_untextured, one.pixels_on_hull);
}
