// The V4L2 driver over the simulated device, over recordings of it, and over
// the checked-in fixtures in fixtures/v4l2/.
#include <gtest/gtest.h>
#include <linux/videodev2.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "capture/pixel_formats.h"
#include "capture/v4l2_camera.h"
#include "capture/v4l2_sim.h"
#include "core/image_metrics.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

// Deterministic test pattern: gradients, colour bars and fine detail.
ImageU8 pattern(uint32_t seq, int w = 160, int h = 120) {
  ImageU8 im(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      // Colour varies smoothly; the edges are in luminance (as in photos).
      const int edge = ((x / 8 + y / 8 + int(seq)) % 2) ? 25 : -25;
      const int c[3] = {20 + (x * 200) / (w - 1), 20 + (y * 200) / (h - 1),
                        128 + static_cast<int>(60 * std::sin(0.05 * (x + 2 * y)))};
      for (int k = 0; k < 3; ++k) im.at(x, y, k) = static_cast<uint8_t>(std::clamp(c[k] + edge, 0, 255));
    }
  return im;
}
ImageU16 depth_pattern(uint32_t seq, int w = 160, int h = 120) {
  ImageU16 d(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) d.at(x, y) = static_cast<uint16_t>(x % 7 == 0 ? 0 : 400 + x + 3 * y + seq);
  return d;
}

V4l2SimConfig sim_config(uint32_t fourcc, V4l2SimFaults faults = {}) {
  V4l2SimConfig c;
  c.formats = {fourcc};
  c.width = 160;
  c.height = 120;
  c.faults = faults;
  c.source = [](uint32_t seq) {
    SimFrame f;
    f.rgb = pattern(seq);
    f.depth = depth_pattern(seq);
    f.timestamp_ns = int64_t(seq) * 33'333'333;
    return f;
  };
  return c;
}

V4l2Config small() {
  V4l2Config c;
  c.width = 160;
  c.height = 120;
  c.timeout_ms = 100;
  c.max_eagain = 50;
  return c;
}

std::unique_ptr<V4l2Camera> open_started(std::unique_ptr<V4l2Io> io, V4l2Config cfg = small()) {
  auto cam = V4l2Camera::open(std::move(io), "/dev/video-test", cfg);
  EXPECT_TRUE(cam) << cam.error().message;
  if (!cam) return nullptr;
  auto st = (*cam)->start();
  EXPECT_TRUE(st) << st.error().message;
  return std::move(*cam);
}

// OpenCV's YUYV conversion is the independent reference for ours.
ImageU8 reference_yuyv(const ImageU8& rgb) {
  const std::string yuyv = rgb_to_yuyv(rgb);
  cv::Mat src(rgb.height, rgb.width, CV_8UC2, const_cast<char*>(yuyv.data())), dst;
  cv::cvtColor(src, dst, cv::COLOR_YUV2RGB_YUYV);
  ImageU8 out(rgb.width, rgb.height, 3);
  std::memcpy(out.data.data(), dst.data, out.data.size());
  return out;
}

TEST(V4l2Camera, YuyvDecodesWithinOneLevelOfTheReference) {
  auto cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV)));
  for (uint32_t i = 0; i < 3; ++i) {
    auto f = cam->grab();
    ASSERT_TRUE(f) << f.error().message;
    const ImageU8 ref = reference_yuyv(pattern(i));
    int worst = 0;
    for (size_t k = 0; k < ref.data.size(); ++k) worst = std::max(worst, std::abs(int(ref.data[k]) - int(f->rgb.data[k])));
    EXPECT_LE(worst, 1);
    EXPECT_GT(*psnr(f->rgb, pattern(i)), 30.0);  // 4:2:2 chroma loss only
  }
}

TEST(V4l2Camera, MjpegGreyAndZ16) {
  auto mjpeg = open_started(make_sim_v4l2_io(sim_config(kFourccMJPG)));
  auto f = mjpeg->grab();
  ASSERT_TRUE(f) << f.error().message;
  EXPECT_GT(*psnr(f->rgb, pattern(0)), 30.0);
  auto grey = open_started(make_sim_v4l2_io(sim_config(kFourccGREY)));
  f = grey->grab();
  ASSERT_TRUE(f);
  const std::string g = rgb_to_grey(pattern(0));
  for (int k = 0; k < 160 * 120; ++k) ASSERT_EQ(f->rgb.data[size_t(k) * 3], static_cast<uint8_t>(g[size_t(k)]));
  auto z = open_started(make_sim_v4l2_io(sim_config(kFourccZ16)));
  f = z->grab();
  ASSERT_TRUE(f);
  EXPECT_EQ(f->depth.data, depth_pattern(0).data);
}

TEST(V4l2Camera, FaultsAreClear) {
  V4l2SimFaults drop;
  drop.drop_frame_at = 1;
  auto cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV, drop)));
  ASSERT_EQ(cam->grab()->dropped_before, 0u);
  ASSERT_EQ(cam->grab()->dropped_before, 1u);

  V4l2SimFaults storm;
  storm.eagain_storm_at = 1;
  storm.eagain_count = 20;
  cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV, storm)));
  ASSERT_TRUE(cam->grab());
  ASSERT_TRUE(cam->grab()) << "20 EAGAINs are retried";
  storm.eagain_count = 500;
  cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV, storm)));
  ASSERT_TRUE(cam->grab());
  auto f = cam->grab();
  ASSERT_FALSE(f);
  EXPECT_NE(f.error().message.find("EAGAIN"), std::string::npos) << f.error().message;

  V4l2SimFaults corrupt;
  corrupt.corrupt_at = 0;
  cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV, corrupt)));
  f = cam->grab();
  ASSERT_TRUE(f);
  EXPECT_EQ(f->sequence, 1u) << "the flagged frame is skipped";
  ASSERT_EQ(cam->warnings().size(), 1u);

  V4l2SimFaults vanish;
  vanish.vanish_at = 2;
  cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV, vanish)));
  ASSERT_TRUE(cam->grab());
  ASSERT_TRUE(cam->grab());
  f = cam->grab();
  ASSERT_FALSE(f);
  EXPECT_NE(f.error().message.find("disconnected"), std::string::npos) << f.error().message;
  EXPECT_TRUE(f.error().is(ErrorCode::disconnected));

  V4l2SimFaults timeout;
  timeout.timeout_at = 0;
  cam = open_started(make_sim_v4l2_io(sim_config(kFourccYUYV, timeout)));
  f = cam->grab();
  ASSERT_FALSE(f);
  EXPECT_NE(f.error().message.find("timed out"), std::string::npos) << f.error().message;
  EXPECT_TRUE(f.error().is(ErrorCode::timeout));
}

// A stride shorter than a row made the Z16 decoder read past the frame
// (found by fuzz/fuzz_v4l2_replay.cpp; the recording is its seed now).
TEST(PixelFormats, FourccNamesAsV4l2CtlPrintsThem) {
  EXPECT_EQ(fourcc_name(kFourccYUYV), "YUYV");
  EXPECT_EQ(fourcc_name(kFourccZ16), "Z16");  // trailing blanks trimmed
  // vivid offers big-endian formats: v4l2_fourcc_be('Y','1','6',' ').
  EXPECT_EQ(fourcc_name(fourcc('Y', '1', '6', ' ') | (1u << 31)), "Y16 -BE");
  EXPECT_EQ(fourcc_name(0), "....");
  for (char c : fourcc_name(0xffffffffu)) EXPECT_TRUE(c >= 0x20 && c < 0x7f);  // ASCII only
}

TEST(PixelFormats, RowsShorterThanTheirPixelsAreErrors) {
  const std::string data(16 * 8 * 2, '\0');
  auto z = z16_to_depth(data, 16, 8, 1);
  ASSERT_FALSE(z);
  EXPECT_NE(z.error().message.find("rows are 1 bytes apart"), std::string::npos) << z.error().message;
  EXPECT_FALSE(yuyv_to_rgb(data, 16, 8, 30));
  EXPECT_FALSE(grey_to_rgb(data, 16, 8, 15));
  EXPECT_TRUE(z16_to_depth(data, 16, 8, 32));
  const fs::path seed = fs::path(S2R_SOURCE_DIR) / "fuzz" / "corpus" / "v4l2_replay" / "regression_z16_short_stride";
  auto io = make_replay_v4l2_io(seed);
  ASSERT_TRUE(io) << io.error().message;
  V4l2Config cfg;
  cfg.width = 160;
  cfg.height = 120;
  auto cam = V4l2Camera::open(std::move(*io), "/dev/video-test", cfg);
  if (cam && (*cam)->start()) (void)(*cam)->grab();  // a clear error or a frame; never a read past the buffer
  // A recorded buffer of 2.7 GB for 160x120 frames is refused before it is allocated.
  io = make_replay_v4l2_io(seed.parent_path() / "regression_huge_buffer");
  ASSERT_TRUE(io) << io.error().message;
  cam = V4l2Camera::open(std::move(*io), "/dev/video-test", cfg);
  ASSERT_TRUE(cam) << cam.error().message;
  auto started = (*cam)->start();
  ASSERT_FALSE(started);
  EXPECT_NE(started.error().message.find("device reports buffer"), std::string::npos) << started.error().message;
}

TEST(V4l2Camera, RefusesWhatItCannotUse) {
  auto cam = V4l2Camera::open(make_kernel_v4l2_io(), "/dev/video-none", small());
  ASSERT_FALSE(cam);
  EXPECT_NE(cam.error().message.find("no V4L2 device"), std::string::npos) << cam.error().message;
  auto c = sim_config(fourcc('N', 'V', '1', '2'));
  cam = V4l2Camera::open(make_sim_v4l2_io(c), "/dev/video-test", small());
  ASSERT_FALSE(cam);
  EXPECT_NE(cam.error().message.find("NV12"), std::string::npos) << cam.error().message;
}

// Records the simulated device (with a dropped frame and an EAGAIN storm),
// then replays the recording through the same driver.
void record(uint32_t fourcc, const fs::path& path, int frames) {
  V4l2SimFaults f;
  f.drop_frame_at = 2;
  f.eagain_storm_at = 3;
  f.eagain_count = 30;
  auto io = make_recording_v4l2_io(make_sim_v4l2_io(sim_config(fourcc, f)), path);
  ASSERT_TRUE(io);
  auto cam = open_started(std::move(*io));
  for (int i = 0; i < frames; ++i) ASSERT_TRUE(cam->grab());
}

void check_replay(uint32_t fourcc, const fs::path& path, int frames) {
  auto io = make_replay_v4l2_io(path);
  ASSERT_TRUE(io) << io.error().message;
  auto cam = open_started(std::move(*io));
  ASSERT_TRUE(cam);
  uint32_t expect_seq = 0;
  for (int i = 0; i < frames; ++i) {
    auto f = cam->grab();
    ASSERT_TRUE(f) << f.error().message;
    if (i == 2) {
      EXPECT_EQ(f->dropped_before, 1u);
      ++expect_seq;
    }
    EXPECT_EQ(f->sequence, expect_seq);
    if (fourcc == kFourccYUYV) {
      const ImageU8 ref = reference_yuyv(pattern(expect_seq));
      int worst = 0;
      for (size_t k = 0; k < ref.data.size(); ++k) worst = std::max(worst, std::abs(int(ref.data[k]) - int(f->rgb.data[k])));
      EXPECT_LE(worst, 1);
    } else if (fourcc == kFourccMJPG) {
      EXPECT_GT(*psnr(f->rgb, pattern(expect_seq)), 30.0);
    } else {
      EXPECT_EQ(f->depth.data, depth_pattern(expect_seq).data);
    }
    ++expect_seq;
  }
}

TEST(V4l2Replay, RecordThenReplayEveryFormat) {
  for (uint32_t f : {kFourccYUYV, kFourccMJPG, kFourccZ16}) {
    const fs::path p = fs::temp_directory_path() / ("s2r_rec_" + std::to_string(getpid()) + fourcc_name(f));
    record(f, p, 6);
    check_replay(f, p, 6);
    fs::remove(p);
  }
}

// Checked-in fixtures (regenerate with S2R_WRITE_FIXTURES=1).
TEST(V4l2Replay, CheckedInFixtures) {
  const fs::path dir = fs::path(S2R_SOURCE_DIR) / "fixtures" / "v4l2";
  for (auto [f, name] : {std::pair{kFourccYUYV, "yuyv_160x120.v4l2rec"}, std::pair{kFourccMJPG, "mjpeg_160x120.v4l2rec"},
                         std::pair{kFourccZ16, "z16_160x120.v4l2rec"}}) {
    if (std::getenv("S2R_WRITE_FIXTURES")) record(f, dir / name, 6);
    ASSERT_TRUE(fs::exists(dir / name)) << dir / name;
    check_replay(f, dir / name, 6);
  }
}

TEST(V4l2Replay, DivergenceAndDamageAreClearErrors) {
  const fs::path dir = fs::path(S2R_SOURCE_DIR) / "fixtures" / "v4l2";
  // Asking a YUYV recording for Z16 makes the driver diverge from it.
  auto io = make_replay_v4l2_io(dir / "yuyv_160x120.v4l2rec");
  ASSERT_TRUE(io);
  auto cfg = small();
  cfg.fourcc = kFourccZ16;
  auto cam = V4l2Camera::open(std::move(*io), "/dev/video-test", cfg);
  ASSERT_FALSE(cam);
  // A truncated recording is rejected on load.
  const fs::path cut = fs::temp_directory_path() / ("s2r_cut_" + std::to_string(getpid()));
  fs::copy_file(dir / "z16_160x120.v4l2rec", cut, fs::copy_options::overwrite_existing);
  fs::resize_file(cut, fs::file_size(cut) - 100);
  auto bad = make_replay_v4l2_io(cut);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("truncated"), std::string::npos) << bad.error().message;
  // A result that is neither a count nor an errno (fuzz: INT_MIN, which
  // the driver negated into an overflow) is rejected on load.
  std::string rec;
  {
    std::ifstream in(dir / "z16_160x120.v4l2rec", std::ios::binary);
    rec.assign(std::istreambuf_iterator<char>(in), {});
  }
  const int64_t int_min = std::numeric_limits<int32_t>::min();
  std::memcpy(rec.data() + 8 + 9, &int_min, 8);  // the first record's result
  {
    std::ofstream(cut, std::ios::binary) << rec;
  }
  bad = make_replay_v4l2_io(cut);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("neither a count nor an errno"), std::string::npos) << bad.error().message;
  fs::remove(cut);
  // A device name that fills its 32 bytes without a NUL (fuzz: strlen ran
  // past the struct; ASan in CI sees any read beyond it).
  auto unnamed = make_replay_v4l2_io(fs::path(S2R_SOURCE_DIR) / "fuzz" / "corpus" / "v4l2_replay" / "regression_card_without_nul");
  ASSERT_TRUE(unnamed) << unnamed.error().message;
  auto named = V4l2Camera::open(std::move(*unnamed), "/dev/video-test", small());
  if (named) {
    EXPECT_LE((*named)->card().size(), sizeof(v4l2_capability::card));
  }
}

}  // namespace
}  // namespace s2r
