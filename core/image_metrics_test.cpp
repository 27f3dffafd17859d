#include "core/image_metrics.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace s2r {
namespace {

TEST(Psnr, HandComputedValues) {
  ImageU8 a(8, 8, 1, 100), b(8, 8, 1, 101);
  EXPECT_NEAR(*psnr(a, b), 10 * std::log10(255.0 * 255.0 / 1.0), 1e-9);  // MSE 1 -> 48.1308 dB
  EXPECT_NEAR(*psnr(a, b), 48.1308036, 1e-6);
  EXPECT_TRUE(std::isinf(*psnr(a, a)));
  EXPECT_EQ(finite_psnr(*psnr(a, a)), kPsnrIdenticalDb);
  EXPECT_EQ(finite_psnr(48.0), 48.0);
  // Mask: outside differs by 50 (ignored), inside by 2 -> MSE 4.
  ImageU8 c = a, mask(8, 8, 1, 0);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      const bool in = x < 4;
      mask.at(x, y) = in ? 255 : 0;
      c.at(x, y) = static_cast<uint8_t>(in ? 102 : 150);
    }
  EXPECT_NEAR(*psnr(a, c, &mask), 10 * std::log10(255.0 * 255.0 / 4.0), 1e-9);
  // Colour: channel errors 0, 3, 6 -> MSE (0 + 9 + 36) / 3 = 15.
  ImageU8 r(4, 4, 3, 50), s(4, 4, 3, 50);
  for (size_t i = 0; i < s.data.size(); ++i) s.data[i] = static_cast<uint8_t>(50 + 3 * (i % 3));
  EXPECT_NEAR(*psnr(r, s), 10 * std::log10(255.0 * 255.0 / 15.0), 1e-9);
}

TEST(Psnr, BadInputIsAnError) {
  ImageU8 a(8, 8, 1), b(8, 7, 1), empty_mask(8, 8, 1, 0);
  EXPECT_FALSE(psnr(a, b));
  EXPECT_FALSE(psnr(a, a, &empty_mask));
  EXPECT_FALSE(psnr(ImageU8{}, ImageU8{}));
}

// For constant images the variances vanish and SSIM reduces to the luminance
// term (2 m1 m2 + C1) / (m1^2 + m2^2 + C1).
double ssim_constants(double m1, double m2) {
  const double C1 = (0.01 * 255) * (0.01 * 255);
  return (2 * m1 * m2 + C1) / (m1 * m1 + m2 * m2 + C1);
}

TEST(Ssim, HandComputedValues) {
  ImageU8 a(24, 24, 1, 100), b(24, 24, 1, 140);
  EXPECT_NEAR(*ssim(a, a), 1.0, 1e-12);
  EXPECT_NEAR(*ssim(a, b), ssim_constants(100, 140), 1e-9);
  // Per channel, then averaged (every channel gets the constants).
  ImageU8 c(24, 24, 3), d(24, 24, 3);
  const int m1[3] = {10, 100, 200}, m2[3] = {20, 100, 120};
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 24; ++x)
      for (int k = 0; k < 3; ++k) {
        c.at(x, y, k) = static_cast<uint8_t>(m1[k]);
        d.at(x, y, k) = static_cast<uint8_t>(m2[k]);
      }
  const double want = (ssim_constants(10, 20) + ssim_constants(100, 100) + ssim_constants(200, 120)) / 3;
  EXPECT_NEAR(*ssim(c, d), want, 1e-9);
}

TEST(Ssim, StructureLowersTheScoreAndMaskSelects) {
  ImageU8 a(32, 32, 1), b(32, 32, 1), mask(32, 32, 1, 0);
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 32; ++x) {
      a.at(x, y) = static_cast<uint8_t>((x / 4 + y / 4) % 2 ? 200 : 50);
      b.at(x, y) = x < 16 ? a.at(x, y) : static_cast<uint8_t>(255 - a.at(x, y));
      mask.at(x, y) = x < 8 ? 255 : 0;
    }
  const double whole = *ssim(a, b);
  EXPECT_LT(whole, 0.5);
  EXPECT_GT(whole, -1.0);
  EXPECT_NEAR(*ssim(a, b, &mask), 1.0, 1e-9);  // the masked half is identical (window stays left of x=16)
}

// A 20x20 square in a 40x40 matte: the band is the ring within 2 px of its
// edge (a 24x24 square less a 16x16 one), plus any fractional pixel.
TEST(MatteError, BandAndErrorsByHand) {
  ImageU8 matte(40, 40, 1, 0);
  for (int y = 10; y < 30; ++y)
    for (int x = 10; x < 30; ++x) matte.at(x, y) = 255;
  auto band = matte_band(matte, 2);
  ASSERT_TRUE(band);
  size_t n = 0;
  for (uint8_t v : band->data) n += v != 0;
  EXPECT_EQ(n, size_t(24 * 24 - 16 * 16));
  EXPECT_EQ(band->at(10, 20), 255);
  EXPECT_EQ(band->at(20, 20), 0);
  EXPECT_EQ(band->at(2, 2), 0);
  matte.at(0, 0) = 100;  // fractional: in the band wherever it lies
  band = matte_band(matte, 2);
  EXPECT_EQ(band->at(0, 0), 255);
  // Identical coverage: no error. A hard square one pixel too wide on every
  // side: 84 pixels off by 1 over 1600, all of them in the band.
  auto same = matte_error(matte, matte, *band);
  ASSERT_TRUE(same);
  EXPECT_EQ(same->mae, 0.0);
  EXPECT_EQ(same->edge_pixels, size_t(24 * 24 - 16 * 16 + 1));
  matte.at(0, 0) = 0;
  band = matte_band(matte, 2);
  ImageU8 fat(40, 40, 1, 0);
  for (int y = 9; y < 31; ++y)
    for (int x = 9; x < 31; ++x) fat.at(x, y) = 255;
  auto e = matte_error(fat, matte, *band);
  ASSERT_TRUE(e);
  EXPECT_NEAR(e->mae, 84.0 / 1600.0, 1e-12);
  EXPECT_NEAR(e->edge_mae, 84.0 / double(24 * 24 - 16 * 16), 1e-12);
  // All inside (the object fills the frame): no silhouette, an empty band.
  auto full = matte_band(ImageU8(8, 8, 1, 255), 2);
  ASSERT_TRUE(full);
  for (uint8_t v : full->data) EXPECT_EQ(v, 0);
  EXPECT_EQ(matte_error(ImageU8(8, 8, 1, 255), ImageU8(8, 8, 1, 255), *full)->edge_pixels, 0u);
}

TEST(MatteError, BadInputIsAnError) {
  EXPECT_FALSE(matte_band(ImageU8(8, 8, 3), 2));
  EXPECT_FALSE(matte_band(ImageU8(8, 8, 1), -1));
  EXPECT_FALSE(matte_band(ImageU8{}, 2));
  const ImageU8 m(8, 8, 1), band(8, 8, 1, 255);
  EXPECT_FALSE(matte_error(ImageU8(8, 7, 1), m, band));
  EXPECT_FALSE(matte_error(ImageU8(8, 8, 4), ImageU8(8, 8, 4), band));
}

// The SSIM loss's gradient against central differences on small random
// images (edges included: the window reaches past them), and its value:
// 1 for identical images, with no gradient there.
TEST(SsimLoss, GradientMatchesFiniteDifferences) {
  ImageF x(13, 9, 3), y(13, 9, 3);
  uint32_t seed = 12345;
  auto rnd = [&] { return float((seed = seed * 1664525u + 1013904223u) >> 8) / float(1 << 24); };
  for (size_t i = 0; i < x.data.size(); ++i) y.data[i] = rnd(), x.data[i] = std::clamp(y.data[i] + 0.3f * (rnd() - 0.5f), 0.f, 1.f);
  ImageF g;
  const double s = ssim_and_gradient(x, y, &g);
  EXPECT_GT(s, 0.0);
  EXPECT_LT(s, 1.0);
  ASSERT_EQ(g.data.size(), x.data.size());
  double worst = 0, largest = 0;
  for (size_t i = 0; i < x.data.size(); i += 7) {
    const float h = 1e-3f, keep = x.data[i];
    x.data[i] = keep + h;
    const double up = ssim_and_gradient(x, y);
    x.data[i] = keep - h;
    const double down = ssim_and_gradient(x, y);
    x.data[i] = keep;
    const double numeric = (up - down) / (2 * h);
    worst = std::max(worst, std::abs(numeric - g.data[i]));
    largest = std::max(largest, std::abs(numeric));
  }
  EXPECT_GT(largest, 1e-4);
  EXPECT_LT(worst, 0.02 * largest) << "largest " << largest;
  EXPECT_NEAR(ssim_and_gradient(y, y, &g), 1.0, 1e-6);
  for (float v : g.data) EXPECT_NEAR(v, 0.f, 1e-6f);
  // Threads share the filters and the bands of rows: the same figure and
  // gradient, to the bit, as one thread.
  ImageF bx(41, 37, 3), by(41, 37, 3), g1, g3;  // three bands of rows
  for (size_t i = 0; i < bx.data.size(); ++i) by.data[i] = rnd(), bx.data[i] = std::clamp(by.data[i] + 0.3f * (rnd() - 0.5f), 0.f, 1.f);
  const double one = ssim_and_gradient(bx, by, &g1, 1), three = ssim_and_gradient(bx, by, &g3, 3);
  EXPECT_EQ(one, three);
  EXPECT_EQ(g1.data, g3.data);
}

}  // namespace
}  // namespace s2r
