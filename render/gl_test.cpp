// Offscreen drawing read back pixel by pixel, and the same drawing in a GLFW
// window under Xvfb giving the same pixels.
#include <epoxy/gl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>

#include "render/framebuffer.h"
#include "render/gl_camera.h"
#include "render/gl_context.h"
#include "render/point_renderer.h"
#include "render/test_xserver.h"

namespace s2r {
namespace {

constexpr int W = 40, H = 30;

Intrinsics camera() {
  Intrinsics k;
  k.width = W; k.height = H; k.fx = 35; k.fy = 36; k.cx = 19.2; k.cy = 14.7;
  return k;
}

// Points placed so that they project exactly onto chosen pixel centres.
struct Expected { int x, y; std::array<uint8_t, 3> rgb; };

std::vector<Expected> scene(std::vector<Eigen::Vector3f>* pts, std::vector<std::array<uint8_t, 3>>* cols) {
  const Intrinsics k = camera();
  std::vector<Expected> want = {{0, 0, {255, 0, 0}}, {39, 0, {0, 255, 0}}, {0, 29, {0, 0, 255}},
                                {39, 29, {255, 255, 0}}, {20, 15, {10, 200, 90}}, {7, 22, {128, 64, 32}}};
  for (const auto& e : want) {
    const double z = 1.5;
    pts->push_back(Eigen::Vector3f(float((e.x - k.cx) / k.fx * z), float((e.y - k.cy) / k.fy * z), float(z)));
    cols->push_back(e.rgb);
  }
  // Occlusion: a farther white point behind pixel (20, 15) loses the depth test.
  pts->push_back(Eigen::Vector3f(float((20 - k.cx) / k.fx * 3.0), float((15 - k.cy) / k.fy * 3.0), 3.0f));
  cols->push_back({255, 255, 255});
  return want;
}

// The test scene into `fb` (the context must be current).
void draw_scene(const Framebuffer& fb) {
  auto r = PointRenderer::create();
  ASSERT_TRUE(r) << r.error().message;
  std::vector<Eigen::Vector3f> pts;
  std::vector<std::array<uint8_t, 3>> cols;
  scene(&pts, &cols);
  r->upload(pts, cols);
  fb.clear(10 / 255.f, 20 / 255.f, 30 / 255.f);
  r->draw(gl_view_projection(camera(), Eigen::Isometry3d::Identity(), 0.1f, 10.f), 1.f);
}

ImageU8 draw(GlContext& ctx) {
  ctx.make_current();
  auto fb = Framebuffer::create(W, H);
  EXPECT_TRUE(fb) << fb.error().message;
  draw_scene(*fb);
  return fb->read_rgb();
}

void check_pixels(const ImageU8& img) {
  std::vector<Eigen::Vector3f> pts;
  std::vector<std::array<uint8_t, 3>> cols;
  const auto want = scene(&pts, &cols);
  ASSERT_EQ(img.width, W);
  ASSERT_EQ(img.height, H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      std::array<uint8_t, 3> expect = {10, 20, 30};
      for (const auto& e : want)
        if (e.x == x && e.y == y) expect = e.rgb;
      for (int c = 0; c < 3; ++c)
        ASSERT_EQ(int(img.at(x, y, c)), int(expect[size_t(c)])) << "pixel " << x << "," << y << " channel " << c;
    }
}

TEST(Headless, DrawAndReadBackPixelByPixel) {
  auto ctx = create_headless_context();
  ASSERT_TRUE(ctx) << ctx.error().message;
  RecordProperty("gl", (*ctx)->describe());
  check_pixels(draw(**ctx));
}

TEST(Headless, ProjectionMatchesTheCameraModel) {
  // gl_projection maps a camera-frame point to the same pixel as Intrinsics::project.
  const Intrinsics k = camera();
  const Eigen::Matrix4f P = gl_projection(k, 0.1f, 10.f);
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.1, -0.2, 1.0), Eigen::Vector3d(-0.3, 0.25, 2.5)}) {
    const Eigen::Vector4f c = P * Eigen::Vector4f(float(p.x()), float(p.y()), float(p.z()), 1.f);
    const float u = (c.x() / c.w() + 1.f) * 0.5f * W - 0.5f;
    const float v = (1.f - c.y() / c.w()) * 0.5f * H - 0.5f;
    const auto px = *k.project(p);
    EXPECT_NEAR(u, px.x(), 1e-4);
    EXPECT_NEAR(v, px.y(), 1e-4);
  }
}

TEST(Window, SameDrawingCodeSamePixelsUnderXvfb) {
  XServer x;
  if (!x.ok()) GTEST_SKIP() << x.reason();
  // The headless image first (one API current per thread at a time).
  ImageU8 from_headless;
  {
    auto headless = create_headless_context();
    ASSERT_TRUE(headless) << headless.error().message;
    from_headless = draw(**headless);
  }
  auto win = GlWindow::create(W, H, "s2r test", true);
  ASSERT_TRUE(win) << win.error().message;
  RecordProperty("gl_window", (*win)->describe());
  const ImageU8 in_window = draw(**win);
  check_pixels(in_window);
  // Blit to the window's back buffer and read it: the screen shows the same.
  auto fb = Framebuffer::create(W, H);
  ASSERT_TRUE(fb);
  draw_scene(*fb);
  int fw = 0, fh = 0;
  (*win)->framebuffer_size(&fw, &fh);
  ASSERT_EQ(fw, W);
  fb->blit_to_screen(fw, fh);
  std::vector<uint8_t> screen(size_t(W) * H * 3);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
  glReadBuffer(GL_BACK);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, W, H, GL_RGB, GL_UNSIGNED_BYTE, screen.data());
  for (int y = 0; y < H; ++y)
    for (int xx = 0; xx < W; ++xx)
      for (int c = 0; c < 3; ++c)
        ASSERT_EQ(screen[(size_t(H - 1 - y) * W + xx) * 3 + c], in_window.at(xx, y, c)) << xx << "," << y;
  (*win)->swap_buffers();
  // And the headless context drew the identical image.
  EXPECT_EQ(from_headless.data, in_window.data);
}

}  // namespace
}  // namespace s2r
