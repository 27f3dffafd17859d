// Building the devices of a capture: real hardware, the simulated rig (real
// driver code over simulated device boundaries), or a replay of a recording.
#pragma once

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>

#include "capture/capture_session.h"
#include "capture/grbl_sim.h"
#include "capture/grbl_turntable.h"
#include "capture/v4l2_camera.h"
#include "capture/v4l2_sim.h"

namespace s2r {

class SynthRig;

struct DeviceOptions {
  int width = 640, height = 480;
  std::chrono::milliseconds settle{300};
  // Record the device boundaries into this folder (color.v4l2rec,
  // depth.v4l2rec, turntable.transcript) for later --replay.
  std::filesystem::path record_dir;
};

struct SimOptions {
  std::string scene = "blob";
  uint64_t seed = 7;
  GrblFaults table_faults;
  V4l2SimFaults color_faults, depth_faults;
};

// Owns whatever stands behind the devices (a simulated firmware, the rig).
struct CaptureRig {
  std::unique_ptr<GrblSim> firmware;
  std::shared_ptr<SynthRig> scene;
  CaptureDevices devices;
  ~CaptureRig();
};

Result<std::unique_ptr<CaptureRig>> make_sim_capture(const SimOptions& sim, const DeviceOptions& options);
Result<std::unique_ptr<CaptureRig>> make_replay_capture(const std::filesystem::path& recording,
                                                        const DeviceOptions& options);
Result<std::unique_ptr<CaptureRig>> make_hardware_capture(const std::string& camera, const std::string& depth,
                                                          const std::string& turntable, const DeviceOptions& options);

// For `s2r devices`: V4L2 nodes, libcamera cameras, serial ports, one per line.
std::vector<std::string> list_capture_devices();

}  // namespace s2r
