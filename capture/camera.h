// One camera interface for colour and depth devices, whatever the driver
// (V4L2, libcamera, replay, the simulated rig). The session code only knows this.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/image.h"
#include "core/result.h"

namespace s2r {

struct CapturedFrame {
  uint32_t fourcc = 0;
  ImageU8 rgb;           // colour and grey formats
  ImageU16 depth;        // Z16
  int64_t timestamp_ns = 0;
  uint32_t sequence = 0;
  uint32_t dropped_before = 0;  // frames the device skipped before this one
};

class Camera {
 public:
  virtual ~Camera() = default;
  virtual Status start() = 0;
  // The next frame; errors say what happened (timeout, device gone, corrupt).
  virtual Result<CapturedFrame> grab() = 0;
  virtual void stop() = 0;
  virtual std::string describe() const = 0;
  virtual int width() const = 0;
  virtual int height() const = 0;
  // What the device did differently from what was asked (a size it adjusted,
  // a control it lacks): the capture writes these into the session's notes.
  virtual const std::vector<std::string>& warnings() const {
    static const std::vector<std::string> none;
    return none;
  }
};

}  // namespace s2r
