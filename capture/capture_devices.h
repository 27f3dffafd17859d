// Building the devices of a capture: real hardware, the simulated rig (real
// driver code over simulated device boundaries), or a replay of a recording.
#pragma once

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>

#include "capture/capture_session.h"
#include "capture/fabscan_turntable.h"
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

// Which turntable firmware is on the other end of a serial port, and how to
// talk to it: grbl (GRBL 1.1), horus (the Ciclop's GRBL 0.9 fork) or fabscan
// (the FabScanPi firmware); capture/grbl_turntable.h and
// capture/fabscan_turntable.h say what each speaks.
struct TurntableChoice {
  std::string protocol = "grbl";
  int baud = 115200;
  bool unlock = false;                // grbl, horus: $X a board that starts in Alarm
  int steps_per_turn = 3200;          // fabscan: motor steps a full turn
  std::chrono::milliseconds settle{300};
  std::filesystem::path transcript;   // every line both ways, appended
};
inline const std::vector<std::string>& turntable_protocols() {
  static const std::vector<std::string> p = {"grbl", "horus", "fabscan"};
  return p;
}
Result<std::unique_ptr<Turntable>> open_turntable(const std::string& port, const TurntableChoice& choice);
// A simulated board of a protocol on a pseudo-terminal (what `--sim` talks to).
struct SimBoard {
  std::unique_ptr<GrblSim> grbl;  // grbl and horus
  std::unique_ptr<FabScanSim> fabscan;
  std::string port() const { return grbl ? grbl->port() : fabscan->port(); }
};
Result<SimBoard> start_sim_board(const std::string& protocol);

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
                                                          const std::string& turntable, const DeviceOptions& options,
                                                          const std::string& protocol = "grbl");
// A real turntable with the simulated colour and depth cameras (`s2r capture
// --turntable TTY --sim-camera`): the rig's scene drawn at the angle the
// table reports after each move, so a table can be checked end to end
// before a camera is bought.
Result<std::unique_ptr<CaptureRig>> make_sim_camera_capture(const std::string& turntable, const std::string& protocol,
                                                            const SimOptions& sim, const DeviceOptions& options);

// For `s2r devices`: V4L2 nodes, libcamera cameras, serial ports, one per line.
std::vector<std::string> list_capture_devices();

}  // namespace s2r
