// The V4L2 driver against recordings of a real kernel driver: Linux 6.1's
// vivid (../shared/data/v4l2_vivid, recorded in a QEMU guest through this
// project's V4L2 recording layer). Every ioctl, buffer and poll result vivid
// answered is replayed: the frames, its dropped-buffer counting, the QBUF
// error, the fatal streaming error and the disconnect it injects.
#include <gtest/gtest.h>

#include <filesystem>

#include "capture/pixel_formats.h"
#include "capture/v4l2_camera.h"
#include "capture/v4l2_io.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

fs::path recording(const char* name) { return fs::path(S2R_DATA_DIR) / "v4l2_vivid" / name; }

#define SKIP_WITHOUT(p) \
  if (!fs::exists(p)) GTEST_SKIP() << (p) << " not found (../shared/data absent)"

Result<std::unique_ptr<V4l2Camera>> open_replay(const fs::path& p, uint32_t fourcc) {
  auto io = make_replay_v4l2_io(p);
  if (!io) return std::unexpected(io.error());
  V4l2Config cfg;  // as recorded: manual exposure, gain and white balance asked for
  cfg.fourcc = fourcc;
  cfg.exposure_100us = 100;
  cfg.gain = 10;
  cfg.white_balance_k = 5000;
  return V4l2Camera::open(std::move(*io), "/dev/video0", cfg);
}

TEST(VividReplay, YuyvAndGreyFrames) {
  for (auto [name, fourcc] : {std::pair{"vivid_YUYV.rec", kFourccYUYV}, std::pair{"vivid_GREY.rec", kFourccGREY}}) {
    SCOPED_TRACE(name);
    const fs::path p = recording(name);
    SKIP_WITHOUT(p);
    auto cam = open_replay(p, fourcc);
    ASSERT_TRUE(cam) << cam.error().message;
    ASSERT_TRUE((*cam)->start());
    EXPECT_EQ((*cam)->width(), 640);
    EXPECT_EQ((*cam)->height(), 480);
    for (uint32_t i = 0; i < 5; ++i) {
      auto f = (*cam)->grab();
      ASSERT_TRUE(f) << f.error().message;
      EXPECT_EQ(f->sequence, i);
      EXPECT_EQ(f->dropped_before, 0u);
      ASSERT_EQ(f->rgb.width, 640);
      // vivid's colour bars: the top-left bar is white (75 % in its default
      // pattern), the frame is not flat.
      int lo = 255, hi = 0;
      for (uint8_t v : f->rgb.data) lo = std::min<int>(lo, v), hi = std::max<int>(hi, v);
      EXPECT_GT(hi - lo, 100);
    }
  }
}

TEST(VividReplay, DroppedBuffersAreCountedExactly) {
  const fs::path p = recording("vivid_drop.rec");
  SKIP_WITHOUT(p);
  auto cam = open_replay(p, kFourccYUYV);
  ASSERT_TRUE(cam) << cam.error().message;
  ASSERT_TRUE((*cam)->start());
  const uint32_t gaps[] = {0, 2, 0, 1, 1, 0, 1, 3};
  for (uint32_t gap : gaps) {
    auto f = (*cam)->grab();
    ASSERT_TRUE(f) << f.error().message;
    EXPECT_EQ(f->dropped_before, gap) << "sequence " << f->sequence;
  }
}

TEST(VividReplay, QbufErrorIsReported) {
  const fs::path p = recording("vivid_inject_vidioc_qbuf_error.rec");
  SKIP_WITHOUT(p);
  auto cam = open_replay(p, kFourccYUYV);
  ASSERT_TRUE(cam) << cam.error().message;
  auto st = (*cam)->start();
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("QBUF"), std::string::npos) << st.error().message;
  EXPECT_EQ(st.error().sys_errno, EINVAL) << st.error().message;
}

// EPOLLERR with the device still present is a fatal streaming error, not a
// disconnect; EPOLLERR with the device gone is a disconnect.
TEST(VividReplay, FatalStreamingErrorIsNotADisconnect) {
  for (bool gone : {false, true}) {
    const fs::path p = recording(gone ? "vivid_disconnect.rec" : "vivid_inject_fatal_streaming_error.rec");
    SKIP_WITHOUT(p);
    SCOPED_TRACE(p.filename().string());
    auto cam = open_replay(p, kFourccYUYV);
    ASSERT_TRUE(cam) << cam.error().message;
    ASSERT_TRUE((*cam)->start());
    Result<CapturedFrame> f;
    int frames = 0;
    while ((f = (*cam)->grab())) ++frames;
    EXPECT_GT(frames, 0);
    if (gone) {
      EXPECT_TRUE(f.error().is(ErrorCode::disconnected)) << f.error().message;
      EXPECT_NE(f.error().message.find("disconnected"), std::string::npos) << f.error().message;
    } else {
      EXPECT_TRUE(f.error().is(ErrorCode::device_fault)) << f.error().message;
      EXPECT_NE(f.error().message.find("fatal streaming error"), std::string::npos) << f.error().message;
      EXPECT_EQ(f.error().message.find("disconnected"), std::string::npos) << f.error().message;
    }
    (*cam)->stop();  // what the recording did next; a replay that diverged says so
  }
}

}  // namespace
}  // namespace s2r
