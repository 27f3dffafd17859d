// A turntable capture session (`s2r capture`): home, N steps of 360/N degrees,
// at each wait for the table to be idle and settled, grab colour and the depth
// frame nearest in time, write the frame atomically, journal it, show progress.
// `resume` continues a killed session after its last complete frame: a re-run
// never duplicates or overwrites a good frame.
#pragma once

#include <atomic>
#include <chrono>
#include <filesystem>
#include <memory>
#include <string>

#include "capture/camera.h"
#include "capture/session.h"
#include "capture/turntable.h"
#include "core/report.h"

namespace s2r {

struct CaptureOptions {
  std::filesystem::path out;
  int steps = 24;
  bool resume = false;
  int flush_frames = 2;   // colour frames dropped after each move (stale buffers)
  int depth_frames = 3;   // depth frames grabbed; the nearest in time to colour is kept
  // Colour and depth timestamps further apart than this cannot come from one
  // clock (one jumped, or the devices use different clocks): the last depth
  // frame is kept, the frame counted (depth_clock_mismatches) and left out
  // of mean_depth_color_dt_ms.
  double max_pair_dt_s = 1.0;
  bool fast_writes = true;  // uncompressed PNG: keeps up with 30 fps at 1280x720 on one core
};

struct CaptureDevices {
  std::unique_ptr<Camera> color;
  std::unique_ptr<Camera> depth;  // may be null
  std::unique_ptr<Turntable> table;
  Session header;  // devices and notes for a new session (root is set from options)
};

// `stop` (may be null) is checked between frames: SIGINT/SIGTERM end the
// session cleanly after the frame in progress.
Result<Report> run_capture(CaptureDevices& devices, const CaptureOptions& options,
                           const std::atomic<bool>* stop = nullptr);

}  // namespace s2r
