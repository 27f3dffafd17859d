// The rasterized cameras' depth against Embree's ray casts of the same mesh:
// pinhole and strongly distorted lenses, triangles wider than the image,
// triangles through the camera plane, a camera inside the surface, and meshes
// with nothing to draw.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "reconstruct/camera_depth.h"
#include "reconstruct/microfacets.h"

using namespace s2r;

namespace {

Intrinsics camera(bool distorted) {
  Intrinsics K;
  K.width = 200, K.height = 150, K.fx = K.fy = 180, K.cx = 99.5, K.cy = 74.5;
  if (distorted) K.dist = {-0.32, 0.11, 0.002, -0.001, -0.01};
  return K;
}

// A latitude-longitude sphere with shared vertices (closed, consistently wound).
Mesh sphere(const Eigen::Vector3f& centre, float radius, int rings, int segments) {
  Mesh m;
  m.vertices.push_back(centre + Eigen::Vector3f(0, radius, 0));
  for (int i = 1; i < rings; ++i) {
    const float th = std::numbers::pi_v<float> * float(i) / float(rings);
    for (int j = 0; j < segments; ++j) {
      const float ph = 2 * std::numbers::pi_v<float> * float(j) / float(segments);
      m.vertices.push_back(centre + radius * Eigen::Vector3f(std::sin(th) * std::cos(ph), std::cos(th), std::sin(th) * std::sin(ph)));
    }
  }
  m.vertices.push_back(centre - Eigen::Vector3f(0, radius, 0));
  const int south = int(m.vertices.size()) - 1;
  auto at = [&](int ring, int seg) { return 1 + (ring - 1) * segments + (seg % segments); };
  for (int j = 0; j < segments; ++j) m.faces.push_back({0, at(1, j + 1), at(1, j)});
  for (int i = 1; i + 1 < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      m.faces.push_back({at(i, j), at(i, j + 1), at(i + 1, j + 1)});
      m.faces.push_back({at(i, j), at(i + 1, j + 1), at(i + 1, j)});
    }
  for (int j = 0; j < segments; ++j) m.faces.push_back({south, at(rings - 1, j), at(rings - 1, j + 1)});
  return m;
}

// A square in the plane y = height, n x n cells of two triangles.
Mesh floor_grid(float half, float height, int n) {
  Mesh m;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j <= n; ++j)
      m.vertices.push_back({-half + 2 * half * float(j) / float(n), height, -half + 2 * half * float(i) / float(n)});
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const int a = i * (n + 1) + j, b = a + 1, c = a + n + 1, d = c + 1;
      m.faces.push_back({a, b, d});
      m.faces.push_back({a, d, c});
    }
  return m;
}

Eigen::Isometry3d looking_at(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
  const Eigen::Vector3d z = (target - eye).normalized();
  const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() << x, z.cross(x), z;
  T.translation() = eye;
  return T;
}

struct Agreement {
  size_t both = 0, only_rays = 0, only_raster = 0;
  float worst = 0;  // largest |difference| where both hit, metres
  size_t close = 0;  // both hit, within 2e-6 of the distance (float rounding)
};

Agreement compare(const Mesh& mesh, const Intrinsics& K, const Eigen::Isometry3d& pose) {
  auto caster = MeshRaycaster::create(mesh);
  EXPECT_TRUE(caster);
  const MeshRasterizer raster(mesh);
  const ImageF a = (*caster)->distance_image(K, pose, 1);
  const ImageF b = raster.distance_image(K, pose);
  Agreement g;
  for (size_t p = 0; p < a.data.size(); ++p) {
    const bool ha = a.data[p] > 0, hb = b.data[p] > 0;
    if (ha && hb) {
      ++g.both;
      const float diff = std::abs(a.data[p] - b.data[p]);
      g.worst = std::max(g.worst, diff);
      g.close += diff <= 2e-6f * a.data[p];
    }
    else if (ha) ++g.only_rays;
    else if (hb) ++g.only_raster;
  }
  return g;
}

}  // namespace

TEST(MeshRasterizer, EqualsRayCastsThroughPinholeAndDistortedLenses) {
  const Mesh m = sphere({0.01f, -0.02f, 0.03f}, 0.05f, 48, 96);
  for (bool distorted : {false, true})
    for (double angle : {0.0, 37.0, 123.0}) {
      const double a = angle * std::numbers::pi / 180;
      const Eigen::Isometry3d pose = looking_at(Eigen::Vector3d(0.3 * std::sin(a), 0.05, -0.3 * std::cos(a)), {0.01, -0.02, 0.03});
      const Agreement g = compare(m, camera(distorted), pose);
      SCOPED_TRACE(testing::Message() << (distorted ? "distorted" : "pinhole") << ", camera at " << angle << " deg");
      EXPECT_GT(g.both, 2000u);
      // Pixel centres on the silhouette may round either way; nowhere else.
      EXPECT_LE(g.only_rays + g.only_raster, 3u) << g.only_rays << " only ray cast, " << g.only_raster << " only rasterized";
      // Rounding alone, but where a ray grazes the surface (near the
      // silhouette) both ways lose digits: a few micrometres there.
      EXPECT_GE(double(g.close), 0.995 * double(g.both));
      EXPECT_LT(g.worst, 5e-5f);
    }
}

TEST(MeshRasterizer, WideTrianglesUnderDistortionAndThroughTheCameraPlane) {
  // A floor of few, large triangles under a camera tilted down: triangles
  // wider than the image, bowed by the lens, and others reaching behind the
  // camera centre.
  const Mesh m = floor_grid(2.f, 0.4f, 3);
  const Eigen::Isometry3d pose = looking_at({0, 0, 0}, {0, 0.3, 1});
  for (bool distorted : {false, true}) {
    SCOPED_TRACE(distorted ? "distorted" : "pinhole");
    const Agreement g = compare(m, camera(distorted), pose);
    EXPECT_GT(g.both, 10000u);
    EXPECT_LE(g.only_rays + g.only_raster, 3u) << g.only_rays << " only ray cast, " << g.only_raster << " only rasterized";
    EXPECT_GE(double(g.close), 0.995 * double(g.both));
    EXPECT_LT(g.worst, 1e-4f);
  }
}

TEST(MeshRasterizer, SharedEdgesLeaveNoCrack) {
  // A fine grid filling the view: every pixel must hit (a crack would be a
  // pixel whose centre falls between two triangles that share an edge).
  const Mesh m = floor_grid(1.f, 0.5f, 120);
  const MeshRasterizer raster(m);
  MeshRasterizer::Stats st;
  const ImageF d = raster.distance_image(camera(false), looking_at({0, 0, 0}, {0, 1, 0.001}), &st);
  size_t misses = 0;
  for (float v : d.data) misses += !(v > 0);
  EXPECT_EQ(misses, 0u);
  EXPECT_EQ(st.triangles_drawn + st.triangles_culled, m.faces.size());
  EXPECT_GT(st.triangles_culled, 0u);  // the grid reaches beyond the view
  // The plane 0.5 m below the centre, straight down the middle pixel.
  EXPECT_NEAR(d.at(100, 75), 0.5, 0.5 * 0.004);
}

TEST(MeshRasterizer, CameraInsideTheSurfaceSeesItEverywhere) {
  const Mesh m = sphere({0, 0, 0}, 1.f, 32, 64);
  const MeshRasterizer raster(m);
  const ImageF d = raster.distance_image(camera(true), Eigen::Isometry3d::Identity());
  for (float v : d.data) {
    ASSERT_GT(v, 0.99f);  // the chords of the polygonised sphere are a little inside it
    ASSERT_LE(v, 1.0001f);
  }
}

TEST(MeshRasterizer, NothingToDrawIsAllMisses) {
  Mesh empty;
  const MeshRasterizer none(empty);
  EXPECT_EQ(none.triangles(), 0u);
  const ImageF a = none.distance_image(camera(false), Eigen::Isometry3d::Identity());
  for (float v : a.data) ASSERT_EQ(v, 0.f);
  // Degenerate and broken faces: repeated vertices, an index past the end, a
  // triangle edge-on to the camera, one behind it.
  Mesh bad;
  bad.vertices = {{0, 0, 1}, {0.1f, 0, 1}, {0, 0.1f, 1}, {0, 0, 2}, {0, 0, -1}, {0.1f, 0, -1}, {0, 0.1f, -1}};
  bad.faces = {{0, 0, 1}, {0, 1, 9}, {0, 3, 1}, {4, 5, 6}};
  const MeshRasterizer r(bad);
  EXPECT_EQ(r.triangles(), 3u);  // the face naming no vertex is dropped
  const ImageF b = r.distance_image(camera(false), Eigen::Isometry3d::Identity());
  for (float v : b.data) ASSERT_EQ(v, 0.f);
}

TEST(MeshRasterizer, BackFacesLeftOutChangeNothingOnAClosedSurface) {
  // The sphere wound with its normals inward (as OpenVDB winds the fused
  // surface): from outside, leaving out the faces turned away gives the same
  // image bit for bit, for about half the triangles.
  Mesh m = sphere({0.02f, -0.01f, 0}, 0.3f, 40, 80);
  for (auto& f : m.faces) {
    const Eigen::Vector3f &a = m.vertices[size_t(f[0])], &b = m.vertices[size_t(f[1])], &c = m.vertices[size_t(f[2])];
    if ((b - a).cross(c - a).dot(a - Eigen::Vector3f(0.02f, -0.01f, 0)) > 0) std::swap(f[1], f[2]);
  }
  // Whole runs of faces turned away are skipped without a per-face test;
  // the images stay the same from far and from just off the surface, where
  // a run's sphere nearly reaches the camera.
  const MeshRasterizer both(m), front(m, MeshRasterizer::Faces::kInwardWound);
  for (const Eigen::Vector3d& eye : {Eigen::Vector3d(0.3, 0.2, -1.1), Eigen::Vector3d(0.05, 0.1, -0.36)})
    for (bool distorted : {false, true}) {
      const Intrinsics K = camera(distorted);
      const Eigen::Isometry3d pose = looking_at(eye, {0, 0, 0});
      MeshRasterizer::Stats sa, sb;
      const ImageF a = both.distance_image(K, pose, &sa), b = front.distance_image(K, pose, &sb);
      size_t hits = 0;
      for (size_t p = 0; p < a.data.size(); ++p) {
        ASSERT_EQ(a.data[p], b.data[p]) << "pixel " << p;
        hits += a.data[p] > 0;
      }
      EXPECT_GT(hits, a.data.size() / 5);
      EXPECT_EQ(sa.back_faces, 0u);
      EXPECT_EQ(sa.back_faces_in_runs, 0u);
      EXPECT_GT(sb.back_faces, m.faces.size() * 4 / 10);
      EXPECT_GT(sb.back_faces_in_runs, sb.back_faces / 4);
      EXPECT_LE(sb.back_faces_in_runs, sb.back_faces);
      EXPECT_LT(sb.triangles_drawn, sa.triangles_drawn * 6 / 10);
    }
  // Seen from inside every face is turned away: nothing is drawn.
  const ImageF inside = front.distance_image(camera(false), Eigen::Isometry3d::Identity());
  for (float v : inside.data) ASSERT_EQ(v, 0.f);
}

TEST(MeshRasterizer, PixelRaysMadeOnlyWhereTrianglesFall) {
  // A small sphere in a corner of the view: its tiles' rays are made, the
  // rest never are, and the image still equals the ray casts.
  const Mesh m = sphere({0.0f, 0.0f, 0.0f}, 0.02f, 24, 48);
  const MeshRasterizer raster(m);
  const Intrinsics K = camera(true);
  const MeshRasterizer::RayTiles none = raster.ray_tiles();
  EXPECT_EQ(none.total, 0u);  // nothing prepared yet
  const Eigen::Isometry3d pose = looking_at({0.05, 0.04, -0.3}, {0.05, 0.04, 0.0});
  raster.prepare(K);
  EXPECT_EQ(raster.ray_tiles().total, 13u * 10u);  // 200 x 150 pixels in 16 x 16 tiles
  EXPECT_EQ(raster.ray_tiles().made, 0u);
  const ImageF b = raster.distance_image(K, pose);
  const MeshRasterizer::RayTiles t = raster.ray_tiles();
  EXPECT_GT(t.made, 0u);
  EXPECT_LT(t.made, t.total / 4);
  auto caster = MeshRaycaster::create(m);
  ASSERT_TRUE(caster);
  const ImageF a = (*caster)->distance_image(K, pose, 1);
  size_t hits = 0, differ = 0;
  for (size_t p = 0; p < a.data.size(); ++p) {
    hits += a.data[p] > 0;
    differ += (a.data[p] > 0) != (b.data[p] > 0) || std::abs(a.data[p] - b.data[p]) > 5e-5f;
  }
  EXPECT_GT(hits, 300u);
  EXPECT_LE(differ, 3u);
  // A lens whose image corners cannot be undistorted (r (1 - 0.5 r^2) peaks
  // below the corners' distorted radius): every tile is made at once and the
  // corners stay without rays.
  Intrinsics folded = camera(false);
  folded.dist = {-0.5, 0, 0, 0, 0};
  const MeshRasterizer other(m);
  other.prepare(folded);
  EXPECT_EQ(other.ray_tiles().made, other.ray_tiles().total);
  const ImageF c = other.distance_image(folded, pose);
  EXPECT_EQ(c.data[0], 0.f);
}

TEST(MeshRasterizer, VisibilityGridDrawsTheWholeImagesRays) {
  // The grid camera's pixel (gx, gy) is the whole camera's (k gx + o, k gy + o):
  // the same ray, so the same distance (float rounding aside).
  const Mesh m = sphere({0.0f, 0.0f, 0.0f}, 0.05f, 32, 64);
  const MeshRasterizer raster(m);
  const Eigen::Isometry3d pose = looking_at({0.02, 0.01, -0.25}, {0.0, 0.0, 0.0});
  for (bool distorted : {false, true})
    for (int k : {2, 3}) {
      const Intrinsics K = camera(distorted), G = visibility_grid(K, k);
      EXPECT_EQ(G.width, (K.width - 1 - (k - 1) / 2) / k + 1);
      const ImageF whole = raster.distance_image(K, pose), grid = raster.distance_image(G, pose);
      ASSERT_EQ(grid.width, G.width);
      size_t hits = 0, differ = 0;
      for (int gy = 0; gy < G.height; ++gy)
        for (int gx = 0; gx < G.width; ++gx) {
          const float a = whole.at(k * gx + (k - 1) / 2, k * gy + (k - 1) / 2), b = grid.at(gx, gy);
          hits += a > 0;
          differ += (a > 0) != (b > 0) || std::abs(a - b) > 2e-6f * a;
        }
      EXPECT_GT(hits, 400u) << "distorted " << distorted << ", k " << k;
      EXPECT_LE(differ, 2u) << "distorted " << distorted << ", k " << k;  // an edge pixel may round the other way
    }
  // 0.45 m / 180 px: 2.5 mm a pixel; the spacing stays within w/3.
  EXPECT_EQ(visibility_stride(0.024, 0.45, camera(false)), 3);
  EXPECT_EQ(visibility_stride(0.015, 0.45, camera(false)), 2);
  EXPECT_EQ(visibility_stride(0.006, 0.45, camera(false)), 1);
  EXPECT_EQ(visibility_stride(0.006, std::numeric_limits<double>::quiet_NaN(), camera(false)), 1);
  // A facet far larger than the image's pixels: the stride stops at the image's side.
  Intrinsics tiny = camera(false);
  tiny.width = 12, tiny.height = 9;
  EXPECT_EQ(visibility_stride(10.0, 0.45, tiny), 9);
  EXPECT_EQ(visibility_grid(tiny, 9).width, 1);  // pixel 4 only (the next, 13, is past the edge)
  EXPECT_EQ(visibility_grid(tiny, 9).height, 1);
}
