// The V4L2 driver against the kernel's own vivid driver, live: run inside the
// QEMU guest of tests/kernel/run-guest (Debian's kernel with vivid loaded);
// everywhere else /dev/video0 is not vivid and every test skips, saying so.
// vivid's error-injection controls (set through VIDIOC_S_CTRL by name, as
// v4l2-ctl names them) make it drop buffers, fail QBUF, raise a fatal
// streaming error and disconnect. With S2R_VIVID_RECORD=DIR each test also
// records the device boundary there (capture/v4l2_io.h), the replay
// fixtures' source (../shared/data/v4l2_vivid).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <filesystem>

#include "capture/capture_devices.h"
#include "capture/grbl_sim.h"
#include "capture/pixel_formats.h"
#include "capture/session.h"
#include "capture/v4l2_camera.h"
#include "capture/v4l2_io.h"
#include "core/progress.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;
constexpr const char* kNode = "/dev/video0";

std::string vivid_card() {
  const int fd = ::open(kNode, O_RDWR | O_NONBLOCK);
  if (fd < 0) return {};
  v4l2_capability cap{};
  std::string driver;
  if (ioctl(fd, VIDIOC_QUERYCAP, &cap) == 0) driver = reinterpret_cast<const char*>(cap.driver);
  ::close(fd);
  return driver;
}

#define REQUIRE_VIVID() \
  if (vivid_card() != "vivid") GTEST_SKIP() << kNode << " is not the vivid driver (run in tests/kernel/run-guest)"

// A vivid control by its v4l2-ctl name ("percentage_of_dropped_buffers").
bool set_vivid_control(const std::string& name, int value) {
  const int fd = ::open(kNode, O_RDWR | O_NONBLOCK);
  if (fd < 0) return false;
  v4l2_queryctrl q{};
  q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
  bool ok = false;
  while (ioctl(fd, VIDIOC_QUERYCTRL, &q) == 0) {
    std::string n;
    for (const char* c = reinterpret_cast<const char*>(q.name); *c; ++c)
      n += std::isalnum(static_cast<unsigned char>(*c)) ? char(std::tolower(static_cast<unsigned char>(*c))) : '_';
    while (n.find("__") != std::string::npos) n.replace(n.find("__"), 2, "_");
    if (n == name) {
      v4l2_control c{q.id, value};
      ok = ioctl(fd, VIDIOC_S_CTRL, &c) == 0;
      break;
    }
    q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
  }
  ::close(fd);
  return ok;
}

Result<std::unique_ptr<V4l2Camera>> open_vivid(const std::string& test, uint32_t fourcc, int width = 640, int height = 480) {
  std::unique_ptr<V4l2Io> io = make_kernel_v4l2_io();
  if (const char* dir = std::getenv("S2R_VIVID_RECORD")) {
    auto rec = make_recording_v4l2_io(std::move(io), fs::path(dir) / ("vivid_" + test + ".rec"));
    if (!rec) return std::unexpected(rec.error());
    io = std::move(*rec);
  }
  V4l2Config cfg;
  cfg.fourcc = fourcc;
  cfg.width = width;
  cfg.height = height;
  cfg.exposure_100us = 100;  // vivid has none of these: said as warnings, not failures
  cfg.gain = 10;
  cfg.white_balance_k = 5000;
  return V4l2Camera::open(std::move(io), kNode, cfg);
}

TEST(VividKernel, FormatsFrameSizesAndFrames) {
  REQUIRE_VIVID();
  for (auto [name, fourcc] : {std::pair{"YUYV", kFourccYUYV}, std::pair{"GREY", kFourccGREY}}) {
    SCOPED_TRACE(name);
    auto cam = open_vivid(name, fourcc);
    ASSERT_TRUE(cam) << cam.error().message;
    EXPECT_EQ((*cam)->card(), "vivid");
    const auto& formats = (*cam)->formats();
    EXPECT_GT(formats.size(), 20u);
    for (uint32_t f : formats) {
      const std::string n = fourcc_name(f);
      EXPECT_TRUE(std::all_of(n.begin(), n.end(), [](char c) { return c >= 0x20 && c < 0x7f; })) << n;
    }
    EXPECT_FALSE((*cam)->warnings().empty());  // no exposure, gain or white balance on vivid
    ASSERT_TRUE((*cam)->start());
    for (uint32_t i = 0; i < 4; ++i) {
      auto f = (*cam)->grab();
      ASSERT_TRUE(f) << f.error().message;
      EXPECT_EQ(f->rgb.width, 640);
      EXPECT_EQ(f->rgb.height, 480);
      int lo = 255, hi = 0;
      for (uint8_t v : f->rgb.data) lo = std::min<int>(lo, v), hi = std::max<int>(hi, v);
      EXPECT_GT(hi - lo, 100);  // vivid's colour bars
    }
    (*cam)->stop();
  }
  // Another of the webcam input's frame sizes; a size it does not offer is
  // granted as the nearest, and said so.
  auto hd = open_vivid("1280x720", kFourccYUYV, 1280, 720);
  ASSERT_TRUE(hd) << hd.error().message;
  EXPECT_EQ((*hd)->width(), 1280);
  EXPECT_EQ((*hd)->height(), 720);
  ASSERT_TRUE((*hd)->start());
  auto big = (*hd)->grab();
  ASSERT_TRUE(big) << big.error().message;
  EXPECT_EQ(big->rgb.width, 1280);
  (*hd)->stop();
  auto odd = open_vivid("320x240", kFourccYUYV, 320, 240);
  ASSERT_TRUE(odd) << odd.error().message;
  EXPECT_EQ((*odd)->width(), 320);
  EXPECT_NE((*odd)->height(), 240);
  bool said = false;
  for (const auto& w : (*odd)->warnings()) said = said || w.find("asked for 320x240") != std::string::npos;
  EXPECT_TRUE(said) << "the granted size is not said";
  // Y16 big-endian, named as v4l2-ctl names it.
  EXPECT_EQ(fourcc_name(v4l2_fourcc('Y', '1', '6', ' ') | (1u << 31)), "Y16 -BE");
}

TEST(VividKernel, DroppedBuffersAreCountedExactly) {
  REQUIRE_VIVID();
  ASSERT_TRUE(set_vivid_control("percentage_of_dropped_buffers", 50));
  auto cam = open_vivid("drop", kFourccYUYV);
  ASSERT_TRUE(cam) << cam.error().message;
  ASSERT_TRUE((*cam)->start());
  uint32_t last = 0, dropped = 0;
  for (int i = 0; i < 12; ++i) {
    auto f = (*cam)->grab();
    ASSERT_TRUE(f) << f.error().message;
    if (i > 0) {
      EXPECT_EQ(f->sequence, last + 1 + f->dropped_before) << i;
    }
    dropped += f->dropped_before;
    last = f->sequence;
  }
  EXPECT_GT(dropped, 0u);
  (*cam)->stop();
  ASSERT_TRUE(set_vivid_control("percentage_of_dropped_buffers", 0));
}

TEST(VividKernel, QbufErrorIsReported) {
  REQUIRE_VIVID();
  auto cam = open_vivid("inject_vidioc_qbuf_error", kFourccYUYV);
  ASSERT_TRUE(cam) << cam.error().message;
  ASSERT_TRUE(set_vivid_control("inject_vidioc_qbuf_error", 1));
  auto st = (*cam)->start();
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("QBUF"), std::string::npos) << st.error().message;
}

TEST(VividKernel, FatalStreamingErrorIsNotADisconnect) {
  REQUIRE_VIVID();
  auto cam = open_vivid("inject_fatal_streaming_error", kFourccYUYV);
  ASSERT_TRUE(cam) << cam.error().message;
  ASSERT_TRUE((*cam)->start());
  ASSERT_TRUE((*cam)->grab());
  ASSERT_TRUE(set_vivid_control("inject_fatal_streaming_error", 1));
  Result<CapturedFrame> f;
  for (int i = 0; i < 20 && (f = (*cam)->grab()); ++i) {
  }
  ASSERT_FALSE(f);
  EXPECT_TRUE(f.error().is(ErrorCode::device_fault)) << f.error().message;
  EXPECT_NE(f.error().message.find("fatal streaming error"), std::string::npos) << f.error().message;
  (*cam)->stop();
}

TEST(VividKernel, AWholeCaptureWithVividAsTheCamera) {
  REQUIRE_VIVID();
  set_progress_enabled(false);
  auto table = GrblSim::start();
  ASSERT_TRUE(table) << table.error().message;
  DeviceOptions d;
  d.settle = std::chrono::milliseconds(0);
  auto rig = make_hardware_capture(kNode, "", (*table)->port(), d);
  ASSERT_TRUE(rig) << rig.error().message;
  const fs::path out = fs::temp_directory_path() / ("s2r_vivid_capture_" + std::to_string(::getpid()));
  fs::remove_all(out);
  CaptureOptions o;
  o.out = out;
  o.steps = 4;
  auto r = run_capture((*rig)->devices, o);
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(out);
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 4u);
  ASSERT_TRUE(s->color);
  EXPECT_EQ(s->color->driver, "v4l2");
  // vivid has no exposure control: what the camera could not do is in the session's notes.
  bool noted = false;
  for (const auto& n : s->notes) noted = noted || n.find("exposure") != std::string::npos;
  EXPECT_TRUE(noted) << "the camera's warnings are not in session.json's notes";
  EXPECT_NE(s->color->device.find("vivid"), std::string::npos) << s->color->device;
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_NEAR(s->frames[i].table_angle_reported_deg, 90.0 * double(i), 0.01);
    auto c = load_color(*s, s->frames[i]);
    ASSERT_TRUE(c) << c.error().message;
    EXPECT_EQ(c->width, 640);
  }
  fs::remove_all(out);
}

// Last: vivid is gone afterwards.
TEST(VividKernel, ZDisconnectIsSaidAsSuch) {
  REQUIRE_VIVID();
  auto cam = open_vivid("disconnect", kFourccYUYV);
  ASSERT_TRUE(cam) << cam.error().message;
  ASSERT_TRUE((*cam)->start());
  ASSERT_TRUE((*cam)->grab());
  ASSERT_TRUE(set_vivid_control("disconnect", 1));
  Result<CapturedFrame> f;
  for (int i = 0; i < 20 && (f = (*cam)->grab()); ++i) {
  }
  ASSERT_FALSE(f);
  EXPECT_TRUE(f.error().is(ErrorCode::disconnected)) << f.error().message;
  EXPECT_NE(f.error().message.find("disconnected"), std::string::npos) << f.error().message;
}

}  // namespace
}  // namespace s2r
