// A FabScanPi turntable (the FabScanPi HAT or an Arduino with the FabScan
// firmware, mariolukas/FabScanPi-Firmware), behind the same Turntable
// interface as GRBL boards:
//
//   link      115200 baud; the firmware echoes every byte it gets, runs a
//             line when its '\n' arrives (";" ends the command within it) and
//             then prints ">" with no line end: the prompt, the only sign
//             that a command, a move included, has finished. It sends no
//             banner and reports no errors: unknown commands are ignored.
//   open      M200 -> its version line (the firmware's only identification);
//             M17 turns the motors on (they start released).
//   move_to   "G04 T<steps> F<feed>;": a relative move of the table stepper
//             by <steps> (signed) at <feed> steps per second, blocking until
//             the prompt. The board keeps no table position: this driver
//             keeps it, in whole steps (so many steps a turn), and turns an
//             absolute target into the steps from there; set_position and
//             home only change that count.
//   faults    no prompt within the move's time plus a margin is a timeout;
//             a board that never prompts after M200 is named as not a
//             FabScan board; an unplugged port (EIO/ENODEV) is said so.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "capture/serial_port.h"
#include "capture/turntable.h"

namespace s2r {

struct FabScanOptions {
  int baud = 115200;
  int steps_per_turn = 3200;  // 200-step motor at 1/16 microstepping, direct drive (FabScanPi's default)
  int feed = 1000;            // steps per second
  std::chrono::milliseconds reply_timeout{2000};
  std::chrono::milliseconds settle{300};
  std::filesystem::path transcript;  // if set, every line in both directions is appended here
};

class FabScanTurntable : public Turntable {
 public:
  static Result<std::unique_ptr<FabScanTurntable>> open(const std::string& port, const FabScanOptions& options = {});
  Status home() override;
  Status set_position(double degrees) override;
  Status move_to(double degrees) override;
  Result<double> position() override;
  std::string describe() const override { return "fabscan:" + port_.path() + " (" + version_ + ")"; }
  const std::string& version() const { return version_; }
  int64_t steps() const { return steps_; }
  // A command and the lines the board printed before its prompt (not the echo).
  Result<std::vector<std::string>> command(const std::string& line, std::chrono::milliseconds timeout);

 private:
  FabScanTurntable(SerialPort port, FabScanOptions o) : port_(std::move(port)), opt_(std::move(o)) {}
  SerialPort port_;
  FabScanOptions opt_;
  std::string version_;
  int64_t steps_ = 0;  // the table's position in motor steps, as this driver counted them
};

// A simulated FabScan firmware on a pseudo-terminal, as the firmware
// behaves: echo, run on '\n', ">" after each command; M200 prints the
// version; G00/G01/G02/G04 T<steps> F<feed> turn the table and block for the
// move's time; M17/M18 turn the motors on/off (a move with the motors off
// turns nothing); M19-M22 lasers, M05 R G B the light ring are accepted;
// anything else is ignored, as the firmware does.
struct FabScanFaults {
  double steps_per_second_scale = 20;  // the simulated table turns this much faster than F says
  int silent_after = -1;               // after n commands the board stops answering
  bool not_fabscan = false;            // a board that echoes nothing and never prompts
};

class FabScanSim {
 public:
  static Result<std::unique_ptr<FabScanSim>> start(int steps_per_turn = 3200, const FabScanFaults& faults = {});
  ~FabScanSim();
  const std::string& port() const { return slave_path_; }
  double position() const;  // the table's angle, degrees, from the steps it turned
  bool motors_on() const;
  int commands() const;
  void unplug();

 private:
  FabScanSim() = default;
  void run();
  void handle(const std::string& line);
  int master_ = -1, slave_ = -1;
  std::string slave_path_;
  int steps_per_turn_ = 3200;
  FabScanFaults faults_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mu_;
  int64_t steps_ = 0;
  bool motors_ = false;
  int commands_ = 0;
};

}  // namespace s2r
