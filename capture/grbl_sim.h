// A simulated GRBL turntable firmware on a pseudo-terminal: the real termios
// code of the turntable link talks to it as to an Arduino. Used by `s2r
// capture --sim` and by the tests, with injectable faults. It can also replay
// a recorded transcript (lines "> host" / "< device") as the device side.
#pragma once

#include <atomic>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "core/result.h"

namespace s2r {

struct GrblFaults {
  int drop_ok_at = -1;         // the n-th G-code line (0-based) gets no "ok"
  int error_at = -1;           // ... is answered "error:20"
  int alarm_at = -1;           // ... triggers "ALARM:2" (soft limit) and the alarm state
  int reset_mid_move_at = -1;  // ... starts a move, then the board resets halfway
  int silent_after = -1;       // after n G-code lines the board stops answering anything
  int garbage_every = 0;       // every n-th reply is preceded by line noise
  bool no_banner = false;      // no banner at start (a Ctrl-X brings one)
  bool start_in_alarm = false;
  double degrees_per_second = 720;
};

class GrblSim {
 public:
  static Result<std::unique_ptr<GrblSim>> start(const GrblFaults& faults = {});
  // Device side from a transcript file recorded by GrblOptions::transcript.
  static Result<std::unique_ptr<GrblSim>> replay(const std::filesystem::path& transcript);
  ~GrblSim();
  const std::string& port() const { return slave_path_; }
  double position() const;  // current table angle (degrees)
  int lines_received() const { return lines_.load(); }
  void unplug();  // closes the device side: the host sees EIO

 private:
  GrblSim() = default;
  void run();
  void run_replay();
  void reply(const std::string& text);
  void handle_line(const std::string& line);
  std::string status_line();
  double position_locked() const;

  int master_ = -1, slave_ = -1;
  std::string slave_path_;
  GrblFaults faults_;
  std::vector<std::pair<char, std::string>> transcript_;
  bool replaying_ = false;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<int> lines_{0};
  mutable std::mutex mu_;
  bool absolute_ = true, alarm_ = false, silent_ = false;
  int gcode_index_ = 0, replies_ = 0;
  double from_ = 0, to_ = 0;
  double move_start_ = 0, move_end_ = 0;  // seconds on a steady clock
  int reset_at_line_ = -1;
};

}  // namespace s2r
