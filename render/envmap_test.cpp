// The multi-scale environment map: g() and its inverse, accuracy against the
// brute-force lobe, and its stiff cases.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <limits>

#include "core/image_io.h"
#include "core/progress.h"
#include "render/envmap.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

struct Quiet : ::testing::Environment {
  void SetUp() override { set_progress_enabled(false); }
};
const auto* const quiet = ::testing::AddGlobalTestEnvironment(new Quiet);

fs::path temp_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("s2r_envmap_" + name + "_" + std::to_string(getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// A sky gradient with a blue half and, optionally, a small sun.
Panorama sky(int w, int h, float sun = 0) {
  ImageF img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float up = 1 - static_cast<float>(y) / h;
      img.at(x, y, 0) = 0.2f + 0.6f * up;
      img.at(x, y, 1) = 0.3f + 0.5f * up;
      img.at(x, y, 2) = x < w / 2 ? 0.9f : 0.4f;
    }
  if (sun > 0)
    for (int y = h / 4; y < h / 4 + 2; ++y)
      for (int x = w / 3; x < w / 3 + 2; ++x)
        for (int c = 0; c < 3; ++c) img.at(x, y, c) = sun;
  return *Panorama::create(std::move(img));
}

TEST(EnvmapExponent, IsFiniteMonotoneAndInvertible) {
  EXPECT_EQ(envmap_exponent(0, 128, 256), 0);  // |t| = 0: a uniform hemisphere
  // Tiny radii: g decays only as log(I) / log(2 / (|t| s)); no overflow of
  // (2 / (|t| s))^2 turns it into 0 early.
  EXPECT_NEAR(envmap_exponent(1e-300, 128, 256), std::log(256) / std::log(2 / 128e-300), 1e-12);
  EXPECT_NEAR(envmap_exponent(1e-100, 128, 256), std::log(256) / std::log(2 / 128e-100), 1e-12);
  EXPECT_GT(envmap_exponent(1e-100, 128, 256), envmap_exponent(1e-300, 128, 256));
  EXPECT_GT(envmap_exponent(4.9e-324, 128, 256), 0);
  // Okumura's (2003) 128^3 map at lambda = 1: L in the tens of thousands.
  EXPECT_NEAR(envmap_exponent(1, 128, 256), 45431.6, 0.5);
  EXPECT_EQ(envmap_exponent(5, 128, 256), envmap_exponent(1, 128, 256));  // clamped
  double last = 0;
  for (double r = 0.001; r <= 1; r += 0.001) {
    const double L = envmap_exponent(r, 128, 256);
    ASSERT_GT(L, last) << r;
    last = L;
    ASSERT_NEAR(envmap_radius(L, 128, 256), r, 1e-9 * std::max(1.0, 1 / r)) << r;
  }
  EXPECT_EQ(envmap_radius(0, 128, 256), 0);
  EXPECT_EQ(envmap_radius(1e12, 128, 256), 1);  // beyond the map's sharpest lobe
  EXPECT_EQ(envmap_radius(std::numeric_limits<double>::quiet_NaN(), 128, 256), 0);
  EXPECT_NEAR(roughness_to_exponent(0), 45431.6, 0.5);
  EXPECT_EQ(roughness_to_exponent(1), 0);
}

TEST(Envmap, ConstantPanoramaGivesTheConstantEverywhere) {
  ImageF img(64, 32, 3);
  for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = (i % 3 == 0) ? 0.25f : 0.5f;
  auto pano = Panorama::create(std::move(img));
  ASSERT_TRUE(pano);
  EnvmapOptions o;
  o.size = 9;  // odd: one voxel sits exactly at t = 0
  auto map = build_envmap(*pano, o);
  ASSERT_TRUE(map) << map.error().message;
  for (int k = 0; k < 9; ++k)
    for (int j = 0; j < 9; ++j)
      for (int i = 0; i < 9; ++i) {
        if (map->voxel_centre(i, j, k).norm() > 1.2) continue;
        const Eigen::Vector3f v = map->voxel(i, j, k);
        ASSERT_NEAR(v[0], 0.25f, 1e-5f) << i << " " << j << " " << k;
        ASSERT_NEAR(v[1], 0.5f, 1e-5f);
      }
}

TEST(Envmap, MatchesTheBruteForceLobeAtEveryLambda) {
  const Panorama pano = sky(256, 128);
  EnvmapOptions o;
  o.size = 24;
  EnvmapStats st;
  auto map = build_envmap(pano, o, &st);
  ASSERT_TRUE(map) << map.error().message;
  EXPECT_GT(st.voxels, 0u);
  EXPECT_GT(st.voxels_outside, 0u);  // the cube's corners are left out
  EXPECT_EQ(st.voxels + st.voxels_outside, 24u * 24 * 24);
  auto acc = envmap_accuracy(*map, pano, 160, 4, false, 3);
  ASSERT_TRUE(acc) << acc.error().message;
  EXPECT_EQ(acc->all.count, 160u);
  for (const auto& b : acc->bands) {
    EXPECT_GT(b.count, 0u);
    EXPECT_LT(b.mean_display, 1.0 / 255) << b.lambda_lo;
  }
  EXPECT_LT(acc->all.max_display, 2.0 / 255);
  // What a renderer sees between voxels: still within a grey level on average.
  auto between = envmap_accuracy(*map, pano, 160, 4, true, 4);
  ASSERT_TRUE(between);
  EXPECT_LT(between->all.mean_display, 1.0 / 255);
}

TEST(Envmap, SunTenThousandTimesTheSkyStaysBoundedAndAccurate) {
  const Panorama pano = sky(256, 128, 1e4f);
  EnvmapOptions o;
  o.size = 24;
  auto map = build_envmap(pano, o);
  ASSERT_TRUE(map);
  // Every voxel is a normalised sum of non-negative weights: within the
  // panorama's range per channel, no ringing, nothing negative.
  for (float v : map->data()) {
    ASSERT_GE(v, 0.f);
    ASSERT_LE(v, 1e4f * (1 + 1e-5f));
  }
  auto acc = envmap_accuracy(*map, pano, 160, 4, false, 5);
  ASSERT_TRUE(acc);
  EXPECT_LT(acc->all.mean_display, 1.0 / 255);
  EXPECT_LT(acc->all.max_relative, 0.05);
}

TEST(Envmap, ExponentsInTheTensOfThousandsStayFinite) {
  // 256 intensity levels at s = 32 give L(1) ~ 2,800; 1e40 levels give ~
  // 47,000: the thesis's sharpest lobes on a map small enough for a unit test.
  const Panorama pano = sky(512, 256, 100);
  EnvmapOptions o;
  o.size = 32;
  o.intensity_levels = 1e40;
  EXPECT_GT(envmap_exponent(1, o.size, o.intensity_levels), 3e4);
  auto map = build_envmap(pano, o);
  ASSERT_TRUE(map);
  for (float v : map->data()) ASSERT_TRUE(std::isfinite(v));
  auto acc = envmap_accuracy(*map, pano, 60, 3, false, 6);
  ASSERT_TRUE(acc);
  EXPECT_LT(acc->bands.back().mean_display, 1.0 / 255);
  // lambda = 1 exactly, and beyond: a finite lookup, close to the panorama.
  const Eigen::Vector3d r(0.3, 0.5, -0.8);
  const Eigen::Vector3f at1 = map->lookup(r.normalized());
  const Eigen::Vector3f mirror = map->reflect(r, 1e12);
  EXPECT_TRUE(at1.allFinite());
  EXPECT_LT((at1 - mirror).norm(), 1e-6f);
  EXPECT_LT((at1 - pano.lookup(r)).norm(), 0.05f);
  // The brute-force reference itself at L = 1e9: finite, the pixel's value.
  auto exact = phong_lobe(pano, r, 1e9);
  ASSERT_TRUE(exact);
  EXPECT_TRUE(exact->allFinite());
}

TEST(Envmap, SaveLoadRoundTripAndValidation) {
  const fs::path d = temp_dir("io");
  EnvmapOptions o;
  o.size = 8;
  auto map = build_envmap(sky(64, 32), o);
  ASSERT_TRUE(map);
  ASSERT_TRUE(map->save(d / "env.exr", "sky"));
  auto back = EnvironmentMap::load(d / "env.exr");
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_EQ(back->size(), 8);
  EXPECT_EQ(back->intensity_levels(), 256);
  ASSERT_EQ(back->data().size(), map->data().size());
  for (size_t i = 0; i < map->data().size(); ++i) ASSERT_NEAR(back->data()[i], map->data()[i], 1e-3f * (1 + map->data()[i]));
  // A plain EXR is not an environment map; a wrong size is named.
  ImageF plain(8, 64, 3);
  ASSERT_TRUE(write_image(d / "plain.exr", plain));
  auto bad = EnvironmentMap::load(d / "plain.exr");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("s2r:format"), std::string::npos) << bad.error().message;
  ASSERT_TRUE(write_exr(d / "wrong.exr", plain, {{"s2r:format", "envmap"}, {"s2r:version", "1"}, {"s2r:size", "9"},
                                                 {"s2r:intensity_levels", "256"}}, true));
  bad = EnvironmentMap::load(d / "wrong.exr");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("size 9"), std::string::npos) << bad.error().message;
  ASSERT_TRUE(write_exr(d / "v2.exr", plain, {{"s2r:format", "envmap"}, {"s2r:version", "2"}}, true));
  bad = EnvironmentMap::load(d / "v2.exr");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("version 2"), std::string::npos) << bad.error().message;
  EXPECT_FALSE(EnvironmentMap::load(d / "missing.exr"));
  fs::remove_all(d);
}

TEST(Envmap, NonFinitePanoramaPixelsAreRefusedOrClampedWithAWarning) {
  const fs::path d = temp_dir("nan");
  ImageF img(16, 8, 3);
  for (float& v : img.data) v = 0.5f;
  img.at(3, 2, 1) = std::numeric_limits<float>::quiet_NaN();
  img.at(5, 4, 0) = std::numeric_limits<float>::infinity();
  img.at(6, 4, 2) = -2;
  ASSERT_TRUE(write_image(d / "bad.exr", img));
  std::vector<std::string> warnings;
  auto refused = load_panorama(d / "bad.exr", false, &warnings);
  ASSERT_FALSE(refused);
  EXPECT_NE(refused.error().message.find("(3, 2)"), std::string::npos) << refused.error().message;
  EXPECT_NE(refused.error().message.find("clamping replaces"), std::string::npos) << refused.error().message;
  auto clamped = load_panorama(d / "bad.exr", true, &warnings);
  ASSERT_TRUE(clamped) << clamped.error().message;
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("1 NaN, 1 infinite and 1 negative"), std::string::npos) << warnings[0];
  EXPECT_EQ(clamped->at(3, 2)[1], 0.f);
  EXPECT_EQ(clamped->at(5, 4)[0], 0.5f);  // +Inf -> the largest finite value
  EXPECT_EQ(clamped->at(6, 4)[2], 0.f);
  fs::remove_all(d);
}

TEST(Envmap, BadOptionsAreClearErrors) {
  const Panorama pano = sky(16, 8);
  EnvmapOptions o;
  o.size = 1;
  EXPECT_FALSE(build_envmap(pano, o));
  o = {};
  o.threshold = 0;
  EXPECT_FALSE(build_envmap(pano, o));
  o = {};
  o.intensity_levels = 1;
  EXPECT_FALSE(build_envmap(pano, o));
  o = {};
  o.samples_per_scale = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(build_envmap(pano, o));
}

}  // namespace
}  // namespace s2r
