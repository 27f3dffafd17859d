// A simulated GRBL turntable firmware on a pseudo-terminal: the real termios
// code of the turntable link talks to it as to an Arduino. Used by `s2r
// capture --sim` and by the tests, with injectable faults. It can also replay
// a recorded transcript (lines "> host" / "< device") as the device side.
//
// It follows GRBL 1.1's documented interface (gnea/grbl, doc/markdown/
// interface.md and report.md) wherever the driver depends on it: status
// reports carry MPos or WPos by $10 (WPos = MPos - WCO), a WCO field in the
// first report after a reset, at once when the offset changes and every 10
// (moving) or 30 (idle) reports, Ov in the second report and every 20, Bf with
// $10 bit 1, Pn while a limit pin is triggered; G92 sets the work offset, not
// the machine position; a limit alarm (ALARM:1 hard, ALARM:2 soft) prints
// "[MSG:Reset to continue]" and then ignores everything, '?' and $X included,
// until a soft reset (Ctrl-X), after which the board is in Alarm until $X or
// $H; G-code in Alarm is answered error:9; an empty line is answered ok; with
// homing enabled ($22=1) the board boots in Alarm; "ok" means the line was
// accepted into the planner, not that the motion ended; '?' is a real-time
// command answered at once, before lines still waiting to be parsed.
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
  // GRBL 1.1 behaviour, not faults:
  int status_mask = 1;          // $10 at start: bit 0 MPos (else WPos), bit 1 Bf
  bool homing_enabled = false;  // $22=1: boots (and resets) in Alarm until $H or $X
  int parse_latency_ms = 0;     // a line is parsed this long after it arrives ('?' at once)
  // Horus (the Ciclop's GRBL 0.9 fork): its banner, 0.9 status reports
  // ("<Idle,MPos:..,WPos:..>"), the motor released until M17 (a move then
  // turns nothing), M70/M71 T<n> lasers, G50 origin reset, G1 F in deg/min.
  bool horus = false;
  // Faults of the link or the board:
  int hard_limit_at = -1;       // the n-th G-code line's move hits a limit switch halfway (ALARM:1)
  int late_ok_at = -1;          // the n-th G-code line's "ok" comes late_ok_ms after it
  int late_ok_ms = 0;
};

class GrblSim {
 public:
  static Result<std::unique_ptr<GrblSim>> start(const GrblFaults& faults = {});
  // Device side from a transcript file recorded by GrblOptions::transcript.
  static Result<std::unique_ptr<GrblSim>> replay(const std::filesystem::path& transcript);
  ~GrblSim();
  const std::string& port() const { return slave_path_; }
  double position() const;          // current table angle in work coordinates (degrees; what the host commands)
  double table_angle() const;       // where the table really stands (differs after moves with the motor released)
  double machine_position() const;  // ... in machine coordinates (the motor's count)
  int lines_received() const { return lines_.load(); }
  void unplug();  // closes the device side: the host sees EIO

 private:
  GrblSim() = default;
  void run();
  void run_replay();
  void reply(const std::string& text);
  void handle_line(const std::string& line);
  void soft_reset();
  void forget_offsets();  // what a reset clears: G92, the report counters
  void limit_alarm(int code);
  void run_due(double t);  // lines whose parse time came, late replies, a reset mid-move
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
  bool locked_ = false;      // after a limit alarm: deaf until a soft reset
  bool limit_pin_ = false;   // a limit switch is pressed (Pn:X)
  bool motor_on_ = true;     // Horus: M17 / M18
  double table_offset_ = 0;  // Horus: machine degrees counted while the motor was released (the table stood)
  int mask_ = 1;             // $10
  double wco_ = 0;           // work coordinate offset of the table axis (G92)
  bool wco_due_ = true;      // report WCO in the next status report
  int reports_ = 0, ov_countdown_ = 2;
  double hard_limit_time_ = -1;  // when the move to a limit switch hits it
  std::vector<std::pair<double, std::string>> pending_lines_;  // (parse time, line)
  std::vector<std::pair<double, std::string>> late_replies_;   // (send time, text)
  int gcode_index_ = 0, replies_ = 0;
  double from_ = 0, to_ = 0;
  double move_start_ = 0, move_end_ = 0;  // seconds on a steady clock
  int reset_at_line_ = -1;
};

}  // namespace s2r
