// The backdrop plate: a fixed camera's view behind a turning object.
#include "reconstruct/backdrop_plate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace s2r {
namespace {

constexpr int kW = 96, kH = 64;

// A textured backdrop (a wall with a corner and a shadow), the same in every
// photo up to sensor noise.
uint8_t wall(int x, int y, int c) { return uint8_t(std::clamp(90 + x + (y > 40 ? -50 : 0) + 20 * c + ((x / 8 + y / 8) % 2) * 30, 0, 255)); }

struct Photos {
  std::vector<ImageU8> images, empty;
  std::vector<const ImageU8*> ptrs() const {
    std::vector<const ImageU8*> p;
    for (const auto& i : images) p.push_back(&i);
    return p;
  }
};

// `n` photos of an object (a disc whose left edge sways with the turn, its
// colour changing) in front of the wall; `noise` levels of sensor noise;
// `moving`: the wall itself slides (a camera that moves, not a turntable).
Photos photos(int n, int noise, bool moving = false) {
  Photos p;
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> jitter(-noise, noise);
  for (int i = 0; i < n; ++i) {
    ImageU8 im(kW, kH, 3), empty(kW, kH, 1, 255);
    const double cx = 48 + 10 * std::sin(i * 0.7), r = 18;
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        const bool object = std::hypot(x - cx, y - 32.0) < r;
        empty.at(x, y) = object ? 0 : 255;
        for (int c = 0; c < 3; ++c)
          im.at(x, y, c) = object ? uint8_t(40 * i % 256) : uint8_t(std::clamp(int(wall(moving ? (x + 9 * i) % kW : x, y, c)) + jitter(rng), 0, 255));
      }
    p.images.push_back(std::move(im));
    p.empty.push_back(std::move(empty));
  }
  return p;
}

TEST(BackdropPlate, IsTheStaticBackdropWhereTheObjectLetsItBeSeen) {
  const Photos p = photos(16, 3);
  const std::array<float, 3> bg{0.5f, 0.5f, 0.5f};
  const auto r = make_backdrop_plate(p.ptrs(), p.empty, bg);
  ASSERT_TRUE(r.plate) << r.skipped;
  EXPECT_EQ(r.plate->width, kW);
  EXPECT_EQ(r.plate->channels, 3);
  EXPECT_LT(r.spread, 3.5);
  // Far from the object's sway the plate is the wall to the noise's median;
  // at the object's centre, which every photo covers, the wall filled in
  // from around the hole (the background colour was 128; the wall's blue
  // channel there is 178 or 208, its rim's 150 to 250).
  int worst = 0;
  for (int y = 0; y < kH; ++y)
    for (int x : {2, 3, 90, 93})
      for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(int(r.plate->at(x, y, c)) - int(wall(x, y, c))));
  EXPECT_LE(worst, 2);
  EXPECT_GT(r.plate->at(48, 32, 2), 150);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.plate->at(48, 32, c), wall(48, 32, c), 45) << c;
  EXPECT_GT(r.filled_share, 0.05);
  EXPECT_NEAR(r.filled_share + r.kept_share, 1.0, 1e-9);
  // Where the disc swings away in a quarter of the photos or more, the wall.
  EXPECT_NEAR(r.plate->at(29, 32, 0), wall(29, 32, 0), 3);
  EXPECT_GT(r.kept_share, 0.6);
  EXPECT_LT(r.kept_share, 0.95);
}

TEST(BackdropPlate, LeftOutWhereNotNeededOrNotStatic) {
  // A uniform backdrop of the background's colour: nothing a colour does not do.
  Photos u = photos(8, 1);
  for (auto& im : u.images)
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x)
        if (u.empty[size_t(&im - u.images.data())].at(x, y))
          for (int c = 0; c < 3; ++c) im.at(x, y, c) = 255;
  auto r = make_backdrop_plate(u.ptrs(), u.empty, {1.f, 1.f, 1.f});
  EXPECT_FALSE(r.plate);
  EXPECT_EQ(r.skipped, "uniform");
  // A backdrop that moves between photos: not one image.
  const Photos m = photos(12, 1, true);
  r = make_backdrop_plate(m.ptrs(), m.empty, {0, 0, 0});
  EXPECT_FALSE(r.plate);
  EXPECT_EQ(r.skipped, "not_static");
  EXPECT_GT(r.spread, 12);
  // Photos of two sizes, none at all, or geometry everywhere.
  Photos d = photos(4, 1);
  d.images[2] = ImageU8(kW / 2, kH / 2, 3);
  EXPECT_EQ(make_backdrop_plate(d.ptrs(), d.empty, {0, 0, 0}).skipped, "views_differ_in_size");
  EXPECT_EQ(make_backdrop_plate({}, {}, {0, 0, 0}).skipped, "no_backdrop_pixels");
  Photos f = photos(4, 1);
  for (auto& e : f.empty) e = ImageU8(kW, kH, 1, 0);
  EXPECT_EQ(make_backdrop_plate(f.ptrs(), f.empty, {0, 0, 0}).skipped, "no_backdrop_pixels");
}

}  // namespace
}  // namespace s2r
