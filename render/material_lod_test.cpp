// Material LOD (Tsutsumi 2010): the threshold lines, and the per-pixel switch
// drawing exactly the detailed method near the eye, the simpler one far
// away, and a continuous mix in between.
#include <gtest/gtest.h>

#include <cmath>

#include "render/gl_context.h"
#include "render/material_lod.h"

namespace s2r {
namespace {

TEST(MaterialLod, SeedThresholdLines) {
  EXPECT_NEAR(seed_material_threshold(0, 0), 59.5, 1e-9);
  EXPECT_NEAR(seed_material_threshold(1000, 0), 331 + 59.5, 1e-9);
  EXPECT_NEAR(seed_material_threshold(200, 200), 0.327 * 200 + 64.7, 1e-9);
  EXPECT_NEAR(seed_material_threshold(600, 600), 0.324 * 600 + 74.0, 1e-9);
  EXPECT_NEAR(seed_material_threshold(500, 1000), 0.327 * 500 + 69.0, 1e-9);
  // Between rows: linear in D; outside 0..1000: clamped.
  EXPECT_NEAR(seed_material_threshold(200, 300), 0.5 * (0.327 * 200 + 64.7 + 0.325 * 200 + 68.8), 1e-9);
  EXPECT_EQ(seed_material_threshold(-5, -5), seed_material_threshold(0, 0));
  EXPECT_EQ(seed_material_threshold(5000, 5000), seed_material_threshold(1000, 1000));
  EXPECT_EQ(normalised_repeats(2), 0);
  EXPECT_EQ(normalised_repeats(10), 1000);
  EXPECT_EQ(normalised_depth(0.05), 500);
}

TEST(MaterialLod, SwitchesPerPixelWithoutPopping) {
  auto ctx = create_headless_context();
  ASSERT_TRUE(ctx) << ctx.error().message;
  const int W = 160, H = 100;
  auto fb = Framebuffer::create(W, H);
  ASSERT_TRUE(fb);
  const MaterialScene scene = material_board_scene(W, H);
  auto r = MaterialRenderer::create(scene.mesh, brick_material(128, 3.6, 0.06));
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_FALSE((*r)->flat());
  auto draw = [&](MaterialMethod m, double blend = 10) {
    MaterialDrawOptions o;
    o.method = m;
    o.blend = blend;
    auto st = (*r)->draw(scene.eye, scene.screen, *fb, o);
    EXPECT_TRUE(st) << st.error().message;
    return fb->read_rgb();
  };
  const ImageU8 pom = draw(MaterialMethod::kParallax), bump = draw(MaterialMethod::kBump), lod = draw(MaterialMethod::kLod),
                vmap = draw(MaterialMethod::kDistanceMap);
  const double T = (*r)->threshold();
  size_t near_px = 0, far_px = 0, band_px = 0, pom_differs = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      if (vmap.at(x, y, 2) != 0) continue;  // sky
      const double V = 1000.0 * (vmap.at(x, y, 0) + vmap.at(x, y, 1) / 255.0) / 255.0;
      bool same_pom = true, same_bump = true, between = true;
      for (int c = 0; c < 3; ++c) {
        same_pom &= lod.at(x, y, c) == pom.at(x, y, c);
        same_bump &= lod.at(x, y, c) == bump.at(x, y, c);
        const int lo = std::min(pom.at(x, y, c), bump.at(x, y, c)), hi = std::max(pom.at(x, y, c), bump.at(x, y, c));
        between &= lod.at(x, y, c) >= lo - 1 && lod.at(x, y, c) <= hi + 1;
        pom_differs += pom.at(x, y, c) != bump.at(x, y, c);
      }
      if (V < T - 10.5) {
        ++near_px;
        EXPECT_TRUE(same_pom) << x << "," << y << " V " << V;
      } else if (V > T + 10.5) {
        ++far_px;
        EXPECT_TRUE(same_bump) << x << "," << y << " V " << V;
      } else {
        ++band_px;
        EXPECT_TRUE(between) << x << "," << y << " V " << V;  // a mix of the two, no third value
      }
    }
  EXPECT_GT(near_px, 500u);
  EXPECT_GT(far_px, 500u);
  EXPECT_GT(band_px, 20u);
  EXPECT_GT(pom_differs, 100u);  // the relief is visible: POM is not bump mapping here
  // A flat material switches bump -> texture, which draw the same.
  auto flat = MaterialRenderer::create(scene.mesh, brick_material(64, 3.6, 0));
  ASSERT_TRUE(flat);
  EXPECT_TRUE((*flat)->flat());
  EXPECT_NEAR((*flat)->threshold(), seed_material_threshold(200, 0), 1e-9);
  // Bad input is named.
  RtMesh no_uv = scene.mesh;
  no_uv.uvs.clear();
  EXPECT_FALSE(MaterialRenderer::create(no_uv, brick_material(16, 4, 0.05)));
  MaterialDrawOptions bad;
  bad.far_m = bad.near_m;
  EXPECT_FALSE((*r)->draw(scene.eye, scene.screen, *fb, bad));
}

}  // namespace
}  // namespace s2r
