// The ray tracer and its visual-field LOD (Mochizuki and Makino;
// docs/references.md):
// the paper's level formula at its singular and boundary points, the
// LOD-equals-full property inside the central field, the reflection budget,
// total internal reflection, ray offsets at large scene scales, determinism,
// bad scenes rejected with a clear error; and what the rig's ground truth
// renders with (curves, procedural albedo, directional lights, intersect).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <memory>
#include <random>

#include "core/image_io.h"
#include "core/mesh.h"
#include "trace/meshes.h"
#include "trace/phong_reference.h"
#include "trace/raytracer.h"
#include "trace/visual_field.h"

namespace s2r {
namespace {

using Eigen::Vector3d;
using Eigen::Vector3f;
using Eigen::Vector3i;

constexpr double kPi = 3.14159265358979323846;

Vector3d horizontal(double deg) { return {std::cos(deg * kPi / 180), std::sin(deg * kPi / 180), 0}; }

TEST(VisualField, LevelAtTheGazeTheEdgesAndBehind) {
  const FieldPoint g = visual_field({1, 0, 0});  // d_r = d_u = 0: exactly along the gaze
  EXPECT_EQ(g.m_a, 0);
  EXPECT_EQ(g.m_b, 0);
  EXPECT_EQ(g.level, 1);
  EXPECT_EQ(visual_field({-1, 0, 0}).level, 0);        // straight behind
  EXPECT_EQ(visual_field({-1, 1e-300, 0}).level, 0);   // behind, tiny offsets
  EXPECT_EQ(visual_field({-1e-300, 0, 0}).level, 0);   // d_f < 0, nearly zero vector
  EXPECT_EQ(visual_field({0, 0, 1}).level, 0);         // straight up: pi/2 > pi/3
  EXPECT_EQ(visual_field({0, 0, -1}).level, 0);        // straight down: pi/2 > 7pi/18
  EXPECT_EQ(visual_field({0, 0, 0}).level, 0);         // no direction
  EXPECT_EQ(visual_field({NAN, 0, 0}).level, 0);
  // d_f = 0 sideways: m_a = pi/2 lies inside the temporal field (5pi/9).
  const FieldPoint side = visual_field({0, 1, 0});
  // (Angles are single precision: within ~1e-7 rad.)
  EXPECT_NEAR(side.m_a, kPi / 2, 1e-7);
  EXPECT_NEAR(side.level, (5.0 / 9 - 0.5) / (5.0 / 9 - 1.0 / 6), 1e-6);  // 1/7
  EXPECT_NEAR(visual_field({0, -1, 0}).level, 1.0 / 7, 1e-6);             // left, same
  // The central field's edge, l = pi/6: level 1 (continuous from both sides).
  EXPECT_NEAR(visual_field(horizontal(30)).level, 1.0, 1e-6);
  EXPECT_NEAR(visual_field(horizontal(30.0001)).level, 1.0, 1e-5);
  // The outer edge, l = L = 5pi/9: level 0, and exactly 0 beyond it.
  EXPECT_NEAR(visual_field(horizontal(100)).level, 0.0, 1e-6);
  EXPECT_EQ(visual_field(horizontal(100.001)).level, 0.0);
  // Upward the field ends at pi/3, downward at 7pi/18.
  EXPECT_GT(visual_field({std::cos(1.2), 0, -std::sin(1.2)}).level, 0);  // 68.8 deg down
  EXPECT_EQ(visual_field({std::cos(1.2), 0, std::sin(1.2)}).level, 0);   // 68.8 deg up
}

TEST(VisualField, MatchesTheSeedFormulaAndStaysBounded) {
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0, 1);
  for (int i = 0; i < 20000; ++i) {
    Vector3d d(n(rng), n(rng), n(rng));
    d *= std::pow(10.0, (i % 13) - 6);  // any length
    const FieldPoint p = visual_field(d);
    const double df = d.x(), dr = d.y(), du = d.z();
    // Eq. 4 and 5 literally (acos arguments clamped, as rounding can push them past 1).
    const double ma = std::acos(std::clamp(df / std::sqrt(df * df + dr * dr), -1.0, 1.0));
    const double mb_abs = std::acos(std::clamp(std::abs(df / std::sqrt(df * df + du * du)), 0.0, 1.0));
    EXPECT_NEAR(p.m_a, ma, 1e-6);  // single precision
    EXPECT_NEAR(p.m_b, du >= 0 ? mb_abs : -mb_abs, 1e-6);
    EXPECT_EQ(field_level(d), p.level);  // the shortcuts change nothing
    ASSERT_TRUE(std::isfinite(p.level));
    EXPECT_GE(p.level, 0);
    EXPECT_LE(p.level, 1);
  }
  // Level falls monotonically away from the gaze in every direction.
  for (double phi = 0; phi < 2 * kPi; phi += 0.3) {
    double last = 1;
    for (double a = 0; a < kPi; a += 0.01) {
      const double lv = visual_field({std::cos(a), std::sin(a) * std::cos(phi), std::sin(a) * std::sin(phi)}).level;
      EXPECT_LE(lv, last + 1e-12);
      last = lv;
    }
  }
}

TEST(VisualField, BatchedLevelsAreTheSameBits) {
  // Random directions of any length, plus the singular ones, in batches.
  std::mt19937 rng(11);
  std::normal_distribution<float> g(0, 1);
  std::uniform_real_distribution<float> scale(-20, 20);
  std::vector<Vector3f> dirs = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0, 0, -1}, {0, -1, 0},
                                {std::cos(0.5235988f), std::sin(0.5235988f), 0}, {0, 0, 0}, {NAN, 0, 0}, {1e30f, 1e30f, 0}};
  while (dirs.size() % kFieldBatch != 0 || dirs.size() < 20000)
    dirs.push_back(Vector3f(g(rng), g(rng), g(rng)) * std::pow(2.0f, scale(rng)));
  for (size_t b = 0; b < dirs.size(); b += kFieldBatch) {
    float f[kFieldBatch], r[kFieldBatch], u[kFieldBatch], lv[kFieldBatch];
    for (int i = 0; i < kFieldBatch; ++i) f[i] = dirs[b + i].x(), r[i] = dirs[b + i].y(), u[i] = dirs[b + i].z();
    field_levels(f, r, u, lv);
    for (int i = 0; i < kFieldBatch; ++i) {
      const float one = field_level(dirs[b + i]);
      ASSERT_EQ(std::memcmp(&lv[i], &one, sizeof(float)), 0) << dirs[b + i].transpose() << ": " << lv[i] << " vs " << one;
      ASSERT_TRUE(lv[i] >= 0 && lv[i] <= 1);
    }
  }
}

TEST(VisualField, EyeFrameForAnyGaze) {
  auto down = EyeFrame::look({0, -1, 0});  // parallel to the world's up: the fallback takes over
  ASSERT_TRUE(down.has_value());
  EXPECT_NEAR((down->right - Vector3d::UnitX()).norm(), 0, 1e-12);
  EXPECT_NEAR(down->forward.dot(down->right), 0, 1e-12);
  EXPECT_NEAR(down->up.norm(), 1, 1e-12);
  EXPECT_EQ(field_level(*down, {0, -1, 0}), 1);
  EXPECT_FALSE(EyeFrame::look({0, 0, 0}).has_value());
  EXPECT_FALSE(EyeFrame::look({NAN, 1, 0}).has_value());
  auto fwd = EyeFrame::look({0, 0, -2});
  ASSERT_TRUE(fwd.has_value());
  EXPECT_NEAR((fwd->up - Vector3d::UnitY()).norm(), 0, 1e-12);
}

// A one-sided quad (two triangles) as an object.
RtObject quad(const Vector3f& a, const Vector3f& b, const Vector3f& c, const Vector3f& d, RtMaterial m = {}) {
  RtObject o;
  o.name = "quad";
  o.mesh.vertices = {a, b, c, d};
  o.mesh.levels = {{Vector3i(0, 1, 2), Vector3i(0, 2, 3)}};
  o.material = m;
  return o;
}

RtObject box(const Vector3f& lo, const Vector3f& hi, RtMaterial m = {}) {
  RtObject o;
  o.name = "box";
  for (int i = 0; i < 8; ++i) o.mesh.vertices.emplace_back(i & 1 ? hi.x() : lo.x(), i & 2 ? hi.y() : lo.y(), i & 4 ? hi.z() : lo.z());
  o.mesh.levels = {{{0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}, {0, 1, 5}, {0, 5, 4},
                    {2, 6, 7}, {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}}};
  o.material = m;
  return o;
}

RtObject sphere(const Vector3d& at, double r, RtMaterial m = {}) {
  Mesh s = icosphere(3);
  RtObject o;
  o.name = "sphere";
  o.mesh.vertices = s.vertices;
  o.mesh.normals = s.normals;
  o.mesh.levels = {s.faces};
  for (auto& v : o.mesh.vertices) v *= static_cast<float>(r);
  o.world_from_object = Eigen::Translation3d(at);
  o.material = m;
  return o;
}

// What the rig's ground truth uses (capture/synth_rig.cpp): round curves,
// procedural albedo, directional lights without shadows, per-ray lights and
// RayTracer::intersect.
RtMaterial matte(float ambient) {
  RtMaterial m;
  m.diffuse = Vector3f::Ones();
  m.ambient = ambient;
  m.specular = Vector3f::Zero();
  m.shininess = 0;
  return m;
}

TEST(RayTracer, CurvesAreHitShadedAndLabelled) {
  RtScene s;
  RtCurves c;
  c.name = "strand";
  c.points = {Eigen::Vector4f(-1, 0, -2, 0.01f), Eigen::Vector4f(1, 0, -2, 0.01f)};
  c.segments = {0};
  c.colors = {Vector3f(0.2f, 0.4f, 0.8f)};
  c.material = matte(0.25f);
  s.curves.push_back(c);
  s.objects.push_back(quad({-5, -5, -4}, {5, -5, -4}, {5, 5, -4}, {-5, 5, -4}, matte(0.25f)));
  s.lights.push_back({Vector3d(0, 0, 1), Vector3f::Ones(), true, false});
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value()) << rt.error().message;
  // Straight at the strand's axis: t = distance - radius, normal back at the eye.
  const RtHit h = (*rt)->intersect({0.3f, 0, 0}, {0, 0, -1});
  ASSERT_TRUE(h.found);
  EXPECT_EQ(h.curves, 0);
  EXPECT_EQ(h.object, -1);
  EXPECT_EQ(h.prim, 0);
  EXPECT_NEAR(h.t, 2 - 0.01f, 1e-5);
  EXPECT_NEAR((h.normal - Vector3f(0, 0, 1)).norm(), 0, 1e-3);
  // Lit head-on by the directional light: colour (ambient + 1), exactly.
  const Vector3f col = (*rt)->trace({0.3, 0, 0}, {0, 0, -1}, 1, 0);
  EXPECT_NEAR((col - 1.25f * c.colors[0]).norm(), 0, 1e-3);
  // Just beside the strand the ray reaches the quad behind.
  const RtHit beside = (*rt)->intersect({0.3f, 0.02f, 0}, {0, 0, -1});
  ASSERT_TRUE(beside.found);
  EXPECT_EQ(beside.object, 0);
  EXPECT_EQ(beside.curves, -1);
  EXPECT_NEAR(beside.t, 4, 1e-5);
}

TEST(RayTracer, IntersectMeasuresAlongTheGivenDirectionUpToTFar) {
  RtScene s;
  s.objects.push_back(quad({-5, -5, -4}, {5, -5, -4}, {5, 5, -4}, {-5, 5, -4}));
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value()) << rt.error().message;
  // A camera ray with z = -1 (the rig's tables) gives depth, not distance.
  const RtHit h = (*rt)->intersect({0, 0, 0}, {0.5f, 0, -1});
  ASSERT_TRUE(h.found);
  EXPECT_NEAR(h.t, 4, 1e-5);
  EXPECT_NEAR((*rt)->intersect({0, 0, 0}, {0, 0, -2}).t, 2, 1e-5);
  EXPECT_FALSE((*rt)->intersect({0, 0, 0}, {0, 0, -1}, 3.9f).found);  // beyond t_far
  EXPECT_FALSE((*rt)->intersect({0, 0, 0}, {0, 0, 1}).found);         // away from everything
  EXPECT_FALSE((*rt)->intersect({0, 0, 0}, {1, 0, 0}).found);
}

TEST(RayTracer, DirectionalLightsWithAndWithoutShadowsAndPerRayLights) {
  // A floor under a blocker; the sun straight above.
  RtScene s;
  s.objects.push_back(quad({-5, -5, 0}, {5, -5, 0}, {5, 5, 0}, {-5, 5, 0}, matte(0.2f)));
  s.objects.push_back(box({-0.5f, -0.5f, 1}, {0.5f, 0.5f, 1.2f}, matte(0.2f)));
  const Vector3d eye(2, 0, 3), at(0, 0, 0);
  const Vector3d dir = at - eye;
  auto with = [&](bool shadows) {
    RtScene t = s;
    t.lights.push_back({Vector3d(0, 0, 5), Vector3f::Ones(), true, shadows});
    auto rt = RayTracer::create(t);
    EXPECT_TRUE(rt.has_value());
    return (*rt)->trace(eye, dir, 1, 0);
  };
  EXPECT_NEAR(with(true).x(), 0.2f, 1e-5);   // in the blocker's shadow: ambient only
  EXPECT_NEAR(with(false).x(), 1.2f, 1e-5);  // shadows off: ambient + n.l = 1
  // Per-ray lights replace the scene's: a sun at 60 deg from the normal.
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value());
  const std::vector<PointLight> tilted{{Vector3d(std::sin(kPi / 3), 0, std::cos(kPi / 3)), Vector3f::Ones(), true, false}};
  EXPECT_NEAR((*rt)->trace(eye, dir, 1, 0, nullptr, &tilted).x(), 0.2f + 0.5f, 1e-5);
  EXPECT_NEAR((*rt)->trace(eye, dir, 1, 0).x(), 0.2f, 1e-5);  // the scene has no lights of its own
}

TEST(RayTracer, ProceduralAlbedoSeesTheWorldPointAndTheRay) {
  RtScene s;
  RtMaterial m = matte(1.0f);
  m.albedo = [](const Vector3f& p, const Vector3f& d) -> Vector3f {
    const bool dark = (static_cast<int>(std::floor(p.x())) + static_cast<int>(std::floor(p.y()))) % 2 != 0;
    return Vector3f::Constant(dark ? 0.1f : 0.9f) * (d.z() < 0 ? 1.0f : 0.5f);
  };
  s.objects.push_back(quad({-5, -5, -1}, {5, -5, -1}, {5, 5, -1}, {-5, 5, -1}, m));
  s.objects[0].world_from_object = Eigen::Translation3d(0, 0, -1);  // the callback gets world points
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value());
  EXPECT_NEAR((*rt)->trace({0.5, 0.5, 0}, {0, 0, -1}, 1, 0).x(), 0.9f, 1e-6);
  EXPECT_NEAR((*rt)->trace({1.5, 0.5, 0}, {0, 0, -1}, 1, 0).x(), 0.1f, 1e-6);
  EXPECT_NEAR((*rt)->trace({0.5, 0.5, -4}, {0, 0, 1}, 1, 0).x(), 0.45f, 1e-6);  // from below
}

TEST(RayTracer, BadCurvesAreRejectedWithTheirName) {
  auto with = [](RtCurves c) {
    RtScene s;
    s.objects.push_back(quad({-5, -5, -4}, {5, -5, -4}, {5, 5, -4}, {-5, 5, -4}));
    c.name = "hair";
    s.curves.push_back(std::move(c));
    auto rt = RayTracer::create(s);
    return rt ? std::string() : rt.error().message;
  };
  RtCurves ok;
  ok.points = {Eigen::Vector4f(0, 0, 0, 0.1f), Eigen::Vector4f(1, 0, 0, 0.1f)};
  ok.segments = {0};
  EXPECT_EQ(with(ok), "");
  RtCurves past = ok;
  past.segments = {1};
  EXPECT_NE(with(past).find("hair"), std::string::npos);
  RtCurves flat = ok;
  flat.points[1].w() = 0;
  EXPECT_NE(with(flat).find("radius"), std::string::npos);
  RtCurves nan = ok;
  nan.points[0].x() = NAN;
  EXPECT_NE(with(nan).find("not finite"), std::string::npos);
  RtCurves colours = ok;
  colours.colors = {Vector3f::Ones(), Vector3f::Ones()};
  EXPECT_NE(with(colours).find("colours"), std::string::npos);
  RtCurves textured = ok;
  textured.material.texture = 0;
  EXPECT_NE(with(textured).find("uvs"), std::string::npos);
}

TEST(RayTracer, ReflectionBudgetIsLevelTimesReflectMax) {
  // Two facing mirrors 1 m apart; a ray along their normal bounces until the budget ends.
  RtMaterial mirror;
  mirror.reflect = 0.9f;
  RtScene s;
  s.objects.push_back(quad({-5, -5, -1}, {5, -5, -1}, {5, 5, -1}, {-5, 5, -1}, mirror));
  s.objects.push_back(quad({-5, -5, 0.5f}, {-5, 5, 0.5f}, {5, 5, 0.5f}, {5, -5, 0.5f}, mirror));
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value()) << rt.error().message;
  for (auto [level, expect] : {std::pair{1.0, 3}, {0.67, 2}, {0.5, 1}, {0.3, 0}}) {
    TraceStats st;
    const Vector3f c = (*rt)->trace({0, 0, 0}, {0, 0, -1}, level, 3, &st);
    EXPECT_EQ(st.secondary, static_cast<size_t>(expect)) << "level " << level;
    EXPECT_EQ(st.depth_cut, 1u);
    EXPECT_TRUE(c.allFinite());
  }
}

TEST(RayTracer, RefractionAndTotalInternalReflection) {
  Vector3f t;
  ASSERT_TRUE(refract_dir({0, 0, -1}, {0, 0, 1}, 1 / 1.5f, &t));  // normal incidence goes straight on
  EXPECT_NEAR((t - Vector3f(0, 0, -1)).norm(), 0, 1e-6);
  const float crit = std::asin(1 / 1.5f);
  EXPECT_TRUE(refract_dir({std::sin(crit - 0.01f), 0, -std::cos(crit - 0.01f)}, {0, 0, 1}, 1.5f, &t));
  EXPECT_FALSE(refract_dir({std::sin(crit + 0.01f), 0, -std::cos(crit + 0.01f)}, {0, 0, 1}, 1.5f, &t));
  EXPECT_TRUE(refract_dir({1, 0, 0}, {0, 0, 1}, 1 / 1.5f, &t));  // grazing entry: finite
  EXPECT_TRUE(t.allFinite());

  // A glass block entered through its top at 45 deg: the refracted ray meets a side face at ~62 deg, past the
  // critical angle, and reflects inside.
  RtMaterial glass;
  glass.transmit = 0.9f;
  glass.reflect = 0.05f;
  RtScene s;
  s.objects.push_back(box({-0.5f, -10, -0.5f}, {0.5f, 0, 0.5f}, glass));
  s.lights.push_back({Vector3d(0, 5, 0), Vector3f(1, 1, 1)});
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value()) << rt.error().message;
  TraceStats st;
  const Vector3f c = (*rt)->trace({-0.5, 0.5, 0}, Vector3d(1, -1, 0), 1.0, 8, &st);
  EXPECT_GE(st.total_internal, 1u);
  EXPECT_TRUE(c.allFinite());
  EXPECT_GE(c.minCoeff(), 0);
  EXPECT_LE(c.maxCoeff(), 2.0f);
}

RtScene lit_sphere_on_floor(double scale, const Vector3d& offset) {
  RtMaterial white;
  white.shininess = 1e6f;  // a huge Phong exponent stays finite (exp(s log cos))
  RtScene s;
  const float k = static_cast<float>(scale);
  RtObject floor = quad({-4 * k, 0, 4 * k}, {4 * k, 0, 4 * k}, {4 * k, 0, -4 * k}, {-4 * k, 0, -4 * k}, white);
  floor.world_from_object = Eigen::Translation3d(offset);
  s.objects.push_back(floor);
  s.objects.push_back(sphere(offset + Vector3d(0, 1, 0) * scale, scale, white));
  s.lights.push_back({offset + Vector3d(2, 5, 1) * scale, Vector3f(1, 1, 1)});
  return s;
}

TEST(RayTracer, NoShadowAcneAtLargeSceneScales) {
  // The same scene at 1 m and at 1 km scale, 10 km from the origin: the offset
  // of secondary-ray origins scales with the coordinates, so the images agree
  // and the lit floor has no self-shadowed speckles.
  auto view = [](double scale, const Vector3d& offset) {
    return Screen::pinhole(offset + Vector3d(0, 3, 6) * scale, {0, -0.4, -1}, {0, 1, 0}, 50, 96, 72);
  };
  const Vector3d far(1e4, 1e4, -1e4);
  auto small = RayTracer::create(lit_sphere_on_floor(1, Vector3d::Zero()));
  auto large = RayTracer::create(lit_sphere_on_floor(1000, far));
  ASSERT_TRUE(small.has_value() && large.has_value());
  TraceOptions o;
  const TraceResult a = (*small)->render(view(1, Vector3d::Zero()), Vector3d(0, 3, 6), o);
  const TraceResult b = (*large)->render(view(1000, far), far + Vector3d(0, 3, 6) * 1000, o);
  const ImageU8 a8 = to_u8(a.color), b8 = to_u8(b.color);
  size_t differ = 0;
  for (size_t i = 0; i < a8.data.size(); ++i) differ += std::abs(int(a8.data[i]) - int(b8.data[i])) > 8;
  EXPECT_LT(differ, a8.data.size() / 200) << "pixels changed by the scale (acne or lost shadows)";
  // Floor pixels in the light (bottom row corners) are lit, not self-shadowed.
  for (const ImageU8* img : {&a8, &b8}) {
    EXPECT_GT(img->at(2, 70, 0), 60);
    EXPECT_GT(img->at(93, 70, 0), 60);
  }
}

TEST(RayTracer, DeterministicWhateverTheThreadsAndTiles) {
  auto rt = RayTracer::create(lit_sphere_on_floor(1, Vector3d::Zero()));
  ASSERT_TRUE(rt.has_value());
  const Screen s = Screen::pinhole({0, 3, 6}, {0, -0.4, -1}, {0, 1, 0}, 50, 80, 60);
  TraceOptions one, many;
  one.threads = 1;
  one.tile = 64;
  many.threads = 2;
  many.tile = 7;
  EXPECT_EQ((*rt)->render(s, {0, 3, 6}, one).color.data, (*rt)->render(s, {0, 3, 6}, many).color.data);
}

TEST(RayTracer, TexturedAndVertexColouredMeshes) {
  RtMaterial m;
  m.ambient = 1;  // no lights: the pixel is the base colour
  m.diffuse = Vector3f::Ones();
  m.texture = 0;
  RtScene s;
  RtObject q = quad({-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}, m);
  q.mesh.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  s.objects.push_back(q);
  ImageU8 tex(2, 2, 3, 0);
  tex.at(0, 0, 0) = 255;  // top left red
  tex.at(1, 1, 2) = 255;  // bottom right blue
  s.textures.push_back(tex);
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value()) << rt.error().message;
  const Vector3f tl = (*rt)->trace({-0.5, 0.5, 5}, {0, 0, -1}, 1, 0);  // uv (0.25, 0.75): a texel centre
  const Vector3f br = (*rt)->trace({0.5, -0.5, 5}, {0, 0, -1}, 1, 0);
  EXPECT_GT(tl.x(), 0.9f);
  EXPECT_LT(tl.z(), 0.1f);
  EXPECT_GT(br.z(), 0.9f);
  EXPECT_LT(br.x(), 0.1f);
}

TEST(RayTracer, BadScenesAreRejectedWithTheirName) {
  EXPECT_FALSE(RayTracer::create(RtScene{}).has_value());
  RtScene s;
  s.objects.push_back(quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}));
  s.objects[0].name = "lamp";
  s.objects[0].mesh.vertices[2].x() = NAN;
  auto bad = RayTracer::create(s);
  ASSERT_FALSE(bad.has_value());
  EXPECT_NE(bad.error().message.find("lamp"), std::string::npos);
  s.objects[0].mesh.vertices[2].x() = 1;
  s.objects[0].material.reflect = 0.7f;
  s.objects[0].material.transmit = 0.7f;
  EXPECT_FALSE(RayTracer::create(s).has_value());
  s.objects[0].material = {};
  s.objects[0].material.texture = 0;
  EXPECT_FALSE(RayTracer::create(s).has_value());  // no such texture
  s.objects[0].material = {};
  s.objects[0].mesh.levels[0][1] = Vector3i(0, 2, 9);
  EXPECT_FALSE(RayTracer::create(s).has_value());  // index out of range
  Screen bad_screen;
  EXPECT_FALSE(bad_screen.validate().has_value());
}

TEST(RayTracer, LodChainFallsAndDetailFollowsEquation10) {
  const Mesh ball = icosphere(5);  // 20480 triangles
  auto chain = build_lod_chain(ball.vertices, ball.faces, 500, 6);
  ASSERT_TRUE(chain.has_value());
  ASSERT_GE(chain->size(), 4u);
  EXPECT_EQ((*chain)[0].size(), ball.faces.size());
  for (size_t k = 1; k < chain->size(); ++k) EXPECT_LT((*chain)[k].size(), (*chain)[k - 1].size());
  EXPECT_LT(chain->back().size(), 700u);
  EXPECT_FALSE(build_lod_chain(ball.vertices, {}, 10, 3).has_value());

  auto mesh = lod_mesh(ball, 5000, 500, 6);
  ASSERT_TRUE(mesh.has_value()) << mesh.error().message;
  EXPECT_LE(mesh->triangles(0), 5000u);
  RtScene s;
  RtObject o;
  o.name = "ball";
  o.mesh = *mesh;
  s.objects.push_back(o);
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value());
  const auto& lv = mesh->levels;
  EXPECT_EQ((*rt)->detail_for(1.0)[0], 0);
  EXPECT_EQ((*rt)->detail_for(0.0)[0], static_cast<int>(lv.size()) - 1);
  for (double level : {0.1, 0.25, 0.5, 0.8}) {
    const int k = (*rt)->detail_for(level)[0];
    const double need = level * double(lv.front().size() - lv.back().size()) + double(lv.back().size());
    EXPECT_GE(double(lv[k].size()), need) << level;  // at least N triangles
    if (k + 1 < static_cast<int>(lv.size())) {
      EXPECT_LT(double(lv[k + 1].size()), need);  // the coarsest that has them
    }
  }
}

TEST(RayTracer, LevelExactlyZeroAndOne) {
  auto rt = RayTracer::create(lit_sphere_on_floor(1, Vector3d::Zero()));
  ASSERT_TRUE(rt.has_value());
  // A screen whose rays straddle the central edge: a one-pixel-wide view
  // centred at 30 deg to the right has level 1 up to rounding.
  const Vector3d eye(0, 1, 5);
  auto gaze = EyeFrame::look({0, 0, -1});
  ASSERT_TRUE(gaze.has_value());
  const double a = kPi / 6;
  Screen s;
  s.name = "edge";
  s.width = s.height = 1;
  s.corner = eye + Vector3d(std::sin(a), 0, -std::cos(a)) - Vector3d(0.5e-9, -0.5e-9, 0);
  s.right = {1e-9, 0, 0};
  s.down = {0, -1e-9, 0};
  TraceOptions o;
  o.field_lod = true;
  o.gaze = *gaze;
  const TraceResult r = (*rt)->render(s, eye, o);
  EXPECT_NEAR(r.level.at(0, 0), 1.0f, 1e-6);
  // At 100 deg to the right the level is 0 and nothing is traced.
  const double b = 100.0 * kPi / 180 + 1e-9;
  s.corner = eye + Vector3d(std::sin(b), 0, -std::cos(b));
  const TraceResult z = (*rt)->render(s, eye, o);
  EXPECT_EQ(z.level.at(0, 0), 0.0f);
  EXPECT_EQ(z.stats.primary, 0u);
  EXPECT_EQ(z.stats.outside_field, 1u);
}

Panorama panorama(int w, int h, const std::function<float(int, int)>& f) {
  ImageF img(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) img.at(x, y) = f(x, y);
  auto p = Panorama::create(img);
  EXPECT_TRUE(p.has_value());
  return *p;
}

TEST(PhongReference, StableAtEveryExponentAndBoundedBySunAndSky) {
  // A uniform sky gives its own value at any exponent, 0 to 1e9.
  const Panorama flat = panorama(64, 32, [](int, int) { return 0.25f; });
  for (double L : {0.0, 1.0, 1e3, 1e6, 1e9}) {
    auto v = phong_lobe(flat, {0.3, 0.5, -0.8}, L);
    ASSERT_TRUE(v.has_value());
    EXPECT_NEAR(v->x(), 0.25, 1e-12) << L;
  }
  // L = 0: the hemisphere's mean; sky above (1), ground below (0).
  const Panorama half = panorama(64, 32, [](int, int y) { return y < 16 ? 1.0f : 0.0f; });
  EXPECT_NEAR(phong_lobe(half, {0, 1, 0}, 0)->x(), 1.0, 1e-12);
  EXPECT_NEAR(phong_lobe(half, {0, 0, -1}, 0)->x(), 0.5, 1e-3);
  // A sun 10^4 times the sky: the lobe climbs from the sky's level to the
  // sun's as L grows, never leaves [sky, sun] (no ringing, nothing negative).
  const Panorama sun = panorama(64, 32, [](int x, int y) { return x == 20 && y == 10 ? 1e4f : 1.0f; });
  const Vector3d at_sun = sun.direction(20, 10);
  double last = 0;
  for (double L : {0.0, 10.0, 1e2, 1e3, 1e4, 1e5, 1e6, 1e8}) {
    const double v = phong_lobe(sun, at_sun, L)->x();
    EXPECT_GE(v, 1.0 - 1e-12);
    EXPECT_LE(v, 1e4 + 1e-6);
    EXPECT_GE(v, last - 1e-9) << L;
    last = v;
  }
  EXPECT_NEAR(last, 1e4, 1.0);  // at L = 1e8 the lobe is the sun's pixel
  // Off the sun by a hair at L = 1e6: still finite (log cos without cancellation).
  auto off = phong_lobe(sun, at_sun + Vector3d(1e-7, 0, 0), 1e6);
  ASSERT_TRUE(off.has_value());
  EXPECT_TRUE(std::isfinite(off->x()));
  // Bad input: a NaN pixel, a negative one, a zero direction, a negative exponent.
  ImageF bad(8, 4, 3, 0.5f);
  bad.at(3, 1, 1) = NAN;
  auto nan_pano = Panorama::create(bad);
  ASSERT_FALSE(nan_pano.has_value());
  EXPECT_NE(nan_pano.error().message.find("(3, 1)"), std::string::npos) << nan_pano.error().message;
  bad.at(3, 1, 1) = -1;
  EXPECT_FALSE(Panorama::create(bad).has_value());
  EXPECT_FALSE(phong_lobe(flat, {0, 0, 0}, 10).has_value());
  EXPECT_FALSE(phong_lobe(flat, {0, 0, 1}, -1).has_value());
  EXPECT_FALSE(phong_lobe(flat, {0, 0, 1}, INFINITY).has_value());
}

TEST(PhongReference, TheTracerReflectsTheExactLobe) {
  RtMaterial gloss;
  gloss.glossy = 1;  // all of the pixel from the lobe
  gloss.glossy_exponent = 50;
  RtScene s;
  s.objects.push_back(sphere({0, 0, 0}, 1, gloss));
  EXPECT_FALSE(RayTracer::create(s).has_value());  // glossy without an environment
  s.environment = std::make_shared<Panorama>(panorama(64, 32, [](int, int y) { return y < 16 ? 0.8f : 0.2f; }));
  auto rt = RayTracer::create(s);
  ASSERT_TRUE(rt.has_value()) << rt.error().message;
  TraceStats st;
  // Straight down onto the top of the sphere: the mirror direction is up.
  const Vector3f top = (*rt)->trace({0, 5, 0}, {0, -1, 0}, 1, 3, &st);
  const Vector3d expect = *phong_lobe(*s.environment, {0, 1, 0}, 50);
  EXPECT_NEAR(top.x(), expect.x(), 1e-3);  // the icosphere's facet tilts the normal slightly
  EXPECT_EQ(st.glossy_lobes, 1u);
  // A ray that leaves the scene sees the panorama, also where a whole tile
  // passes beside the scene and is not traced.
  EXPECT_NEAR((*rt)->trace({3, 0, 0}, {0, -1, 0}, 1, 3).x(), 0.2f, 1e-6);
  const TraceResult img = (*rt)->render(Screen::pinhole({0, 0, 5}, {0, 1, 0}, {0, 0, 1}, 40, 32, 32), {0, 0, 5}, {});
  EXPECT_EQ(img.stats.empty_tiles_pixels, 32u * 32u);
  EXPECT_NEAR(img.color.at(16, 16, 0), 0.8f, 1e-6);  // looking up: the sky
}

}  // namespace
}  // namespace s2r
