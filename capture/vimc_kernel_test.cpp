// The libcamera camera against the kernel's vimc driver, live: run inside the
// QEMU guest of tests/kernel/run-guest (vimc built from Debian's kernel
// source, udev running, Debian's libcamera 0.0.3 with its vimc pipeline);
// everywhere else libcamera finds no vimc and every test skips, saying so.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>

#include "capture/capture_devices.h"
#include "capture/grbl_sim.h"
#include "capture/libcamera_camera.h"
#include "capture/pixel_formats.h"
#include "capture/session.h"
#include "core/progress.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

std::string vimc_camera() {
  for (const auto& c : list_libcamera_cameras())
    if (c.find("vimc") != std::string::npos) return c.substr(0, c.find(" ("));
  return {};
}

#define REQUIRE_VIMC()                 \
  const std::string id = vimc_camera(); \
  if (id.empty()) GTEST_SKIP() << "libcamera finds no vimc camera (run in tests/kernel/run-guest with vimc and udev)"

TEST(VimcKernel, ListsOpensAtTheGrantedSizeAndSaysSo) {
  REQUIRE_VIMC();
  EXPECT_NE(id.find("Sensor B"), std::string::npos) << id;
  auto cam = LibcameraCamera::open(id, 640, 480);
  ASSERT_TRUE(cam) << cam.error().message;
  // vimc's pipeline makes 636x480 of 640x480: granted, and said.
  EXPECT_GT((*cam)->width(), 0);
  if ((*cam)->width() != 640 || (*cam)->height() != 480) {
    ASSERT_FALSE((*cam)->warnings().empty());
    EXPECT_NE((*cam)->warnings()[0].find("asked for 640x480, granted"), std::string::npos) << (*cam)->warnings()[0];
  }
  ASSERT_TRUE((*cam)->start());
  for (int i = 0; i < 3; ++i) {
    auto f = (*cam)->grab();
    ASSERT_TRUE(f) << f.error().message;
    EXPECT_EQ(f->fourcc, kFourccBGR3);  // the real pixel format, not 0
    EXPECT_EQ(f->rgb.width, (*cam)->width());
    EXPECT_EQ(f->rgb.height, (*cam)->height());
    int lo = 255, hi = 0;
    for (uint8_t v : f->rgb.data) lo = std::min<int>(lo, v), hi = std::max<int>(hi, v);
    EXPECT_GT(hi - lo, 50);  // vimc's sensor test pattern
  }
  (*cam)->stop();
}

TEST(VimcKernel, AWholeCaptureWithLibcameraAsTheCamera) {
  REQUIRE_VIMC();
  set_progress_enabled(false);
  auto table = GrblSim::start();
  ASSERT_TRUE(table) << table.error().message;
  DeviceOptions d;
  d.settle = std::chrono::milliseconds(0);
  auto rig = make_hardware_capture("libcamera:" + id, "", (*table)->port(), d);
  ASSERT_TRUE(rig) << rig.error().message;
  const fs::path out = fs::temp_directory_path() / ("s2r_vimc_capture_" + std::to_string(::getpid()));
  fs::remove_all(out);
  CaptureOptions o;
  o.out = out;
  o.steps = 3;
  auto r = run_capture((*rig)->devices, o);
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(out);
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 3u);
  ASSERT_TRUE(s->color);
  EXPECT_EQ(s->color->driver, "libcamera");
  // What the pipeline granted differently is in session.json's notes.
  if (s->color->intrinsics.width != 640) {
    bool noted = false;
    for (const auto& n : s->notes) noted = noted || n.find("granted") != std::string::npos;
    EXPECT_TRUE(noted);
  }
  auto c = load_color(*s, s->frames[2]);
  ASSERT_TRUE(c) << c.error().message;
  EXPECT_EQ(c->width, s->color->intrinsics.width);
  fs::remove_all(out);
}

}  // namespace
}  // namespace s2r
