// A simulated UVC camera behind the V4l2Io boundary: the real V4L2 driver
// code (v4l2_camera.h) runs against it. Frames come from a callback (the
// synthetic rig, or test images) and are encoded into the raw format the
// driver negotiated (YUYV, MJPEG, GREY, Z16), as a device would.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "capture/v4l2_io.h"
#include "core/image.h"

namespace s2r {

struct SimFrame {
  ImageU8 rgb;      // for colour formats
  ImageU16 depth;   // for Z16
  int64_t timestamp_ns = 0;
};

struct V4l2SimFaults {
  int drop_frame_at = -1;     // the n-th delivered frame skips one sequence number
  int eagain_storm_at = -1;   // before the n-th frame: `eagain_count` DQBUF EAGAINs
  int eagain_count = 0;
  int corrupt_at = -1;        // the n-th frame carries V4L2_BUF_FLAG_ERROR
  int vanish_at = -1;         // from the n-th frame on: ENODEV (unplugged)
  int timeout_at = -1;        // the n-th poll times out
  int eio_at = -1;            // the n-th frame's DQBUF fails with EIO (a USB transfer error), once
  int clock_jump_at = -1;     // from the n-th frame on, timestamps are shifted by clock_jump_ns
  int64_t clock_jump_ns = 0;
};

struct V4l2SimConfig {
  std::string card = "s2r simulated UVC camera";
  std::vector<uint32_t> formats;  // offered fourccs
  int width = 640, height = 480;  // the only size offered
  V4l2SimFaults faults;
  // Called for each frame the device delivers (sequence number given).
  std::function<SimFrame(uint32_t sequence)> source;
};

std::unique_ptr<V4l2Io> make_sim_v4l2_io(V4l2SimConfig config);

}  // namespace s2r
