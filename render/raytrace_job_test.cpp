// The CAVE scenes of Mochizuki and Makino through the tracer: the visual-field
// LOD render equals the full render inside the central field and is
// background outside (scenes A and C, three gazes), also with the Stanford
// bunny.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "core/mesh.h"
#include "render/raytrace_job.h"
#include "trace/meshes.h"
#include "trace/raytracer.h"
#include "trace/visual_field.h"

namespace s2r {
namespace {

using Eigen::Vector3d;

// The check on the paper's scenes (icosphere stand-ins here; the bench
// uses the bunny): identical inside the central field, background outside.
TEST(RayTracer, FieldLodEqualsFullInTheCentreAndSkipsOutside) {
  SeedSceneOptions so;
  so.n_max = 1280;
  so.n_min = 80;
  for (char scene : {'A', 'C'}) {
    so.scene = scene;
    auto s = seed_scene(icosphere(4), so);
    ASSERT_TRUE(s.has_value()) << s.error().message;
    auto rt = RayTracer::create(*s);
    ASSERT_TRUE(rt.has_value());
    const auto screens = cave_screens(48);
    TraceOptions full;
    const LayoutRender ref = render_layout(**rt, screens, cave_default_eye(), full);
    for (const Vector3d& gaze : {Vector3d(0, 0, -1), Vector3d(0, -1, 0), Vector3d(1, 0, -1)}) {
      TraceOptions lod;
      lod.field_lod = true;
      lod.gaze = *EyeFrame::look(gaze);
      const LayoutRender got = render_layout(**rt, screens, cave_default_eye(), lod);
      EXPECT_TRUE(std::isinf(psnr_where(got, ref, 1.0, 1.0))) << scene << " gaze " << gaze.transpose();
      EXPECT_GT(got.stats.outside_field, 0u);
      EXPECT_GT(got.stats.central, 0u);
      for (const auto& w : got.walls)
        for (size_t p = 0; p < w.level.pixels(); ++p) {
          if (w.level.data[p] > 0) continue;
          for (int c = 0; c < 3; ++c) ASSERT_EQ(w.color.data[p * 3 + c], s->background[c]);
        }
      EXPECT_LE(got.stats.primary + got.stats.secondary, ref.stats.primary + ref.stats.secondary);
    }
  }
}

TEST(RayTracer, SeedSceneWithTheStanfordBunny) {
  auto bunny = read_ply_mesh(std::filesystem::path(S2R_DATA_DIR) / "stanford_bunny" / "bun_zipper.ply");
  if (!bunny) GTEST_SKIP() << bunny.error().message;
  SeedSceneOptions so;
  so.scene = 'C';
  auto s = seed_scene(*bunny, so);
  ASSERT_TRUE(s.has_value()) << s.error().message;
  EXPECT_EQ(s->objects.size(), 8u);
  EXPECT_LE(s->objects[0].mesh.triangles(0), 5804u);
  EXPECT_GE(s->objects[0].mesh.triangles(0), 5000u);
  EXPECT_LE(s->objects[0].mesh.levels.back().size(), 650u);
  auto rt = RayTracer::create(*s);
  ASSERT_TRUE(rt.has_value());
  TraceOptions full, lod;
  lod.field_lod = true;
  lod.gaze = *EyeFrame::look({0, -1, 0});
  const auto screens = cave_screens(64);
  const LayoutRender ref = render_layout(**rt, screens, cave_default_eye(), full);
  const LayoutRender got = render_layout(**rt, screens, cave_default_eye(), lod);
  const double central = psnr_where(got, ref, 1.0, 1.0);
  EXPECT_GE(central, 50.0);
  EXPECT_GT(ref.stats.secondary, 300u);  // the mirrors reflect
  EXPECT_LT(got.stats.secondary, ref.stats.secondary / 4);
}

}  // namespace
}  // namespace s2r
