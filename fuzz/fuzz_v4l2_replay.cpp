// A V4L2 recording (capture/v4l2_io.h) replayed through the real driver
// (capture/v4l2_camera.h): open, negotiate, map buffers, grab, decode. What the
// recording says the device answered is as untrusted as a real device.
#include "capture/v4l2_camera.h"
#include "capture/v4l2_io.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = s2r::fuzz::scratch().write("camera.v4l2rec", {reinterpret_cast<const char*>(data), size});
  auto io = s2r::make_replay_v4l2_io(path);
  if (!io) return 0;
  s2r::V4l2Config cfg;
  cfg.width = 160;
  cfg.height = 120;
  cfg.timeout_ms = 10;
  auto cam = s2r::V4l2Camera::open(std::move(*io), "/dev/video-fuzz", cfg);
  s2r::fuzz::report(cam);
  if (!cam) return 0;
  if ((*cam)->start()) {
    for (int i = 0; i < 3; ++i)
      if (!(*cam)->grab()) break;
    (*cam)->stop();
  }
  return 0;
}
