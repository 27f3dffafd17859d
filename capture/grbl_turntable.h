// A DIY turntable on an Arduino running GRBL-style firmware: GRBL 1.1 itself,
// or Horus (the Ciclop scanner's GRBL 0.9 fork, bqlabs/horus-fw): 115200
// baud, the table is the X axis in degrees. Horus differs in its banner
// ("Horus 0.1 ['$' for help]"), its status reports (GRBL 0.9's
// "<Idle,MPos:x,y,z,WPos:x,y,z>"), motors that start released (M17 turns
// them on), moves as "G1 X<deg> F<deg/min>" and G50 to take the current
// angle as 0, as its own host software sends them.
//
//   open      the board resets when the port opens and prints a banner
//             ("Grbl 1.1h ['$' for help]"); without one we send Ctrl-X (soft
//             reset) and wait again.
//   move_to   "G90 G0 X<deg>" -> "ok" | "error:N" | "ALARM:N", then "?" status
//             polls ("<Run|MPos:..>" ... "<Idle|MPos:..>"), then a settle time.
//   position  status reports carry MPos or WPos by the board's $10; moves and
//             G92 are in work coordinates, so an MPos report is turned into
//             the work position with the last WCO the board sent
//             (WPos = MPos - WCO; GRBL sends WCO after a reset, when it
//             changes and every 10-30 reports).
//   faults    error:N and ALARM:N map to messages with GRBL's meaning; a lost
//             "ok" is recovered by the status poll (absolute moves are safe to
//             re-check), and one that comes late is matched to its own
//             command before the next is sent; after a limit alarm
//             ("[MSG:Reset to continue]") GRBL ignores everything until a
//             reset, which is said as such, not as silence; garbage bytes and
//             partial lines are skipped; silence is retried then reported; a
//             reset mid-move (a new banner) and an unplugged board
//             (EIO/ENODEV) are reported as such.
#pragma once

#include <chrono>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "capture/serial_port.h"
#include "capture/turntable.h"

namespace s2r {

struct GrblOptions {
  int baud = 115200;
  std::chrono::milliseconds banner_timeout{2500};
  std::chrono::milliseconds reply_timeout{1000};
  std::chrono::milliseconds move_timeout{60000};
  std::chrono::milliseconds poll_interval{20};
  std::chrono::milliseconds settle{300};
  int retries = 3;              // status polls that may go unanswered in a row
  bool unlock_alarm = false;    // send $X if the board starts in alarm
  std::string axis = "X";
  std::string dialect = "grbl";   // grbl | horus
  double feed_deg_per_min = 600;  // horus: the G1 feed
  std::filesystem::path transcript;  // if set, every line in both directions is appended here
};

struct GrblStatus {
  std::string state;      // Idle, Run, Hold, Alarm, Home, Jog, Door, Check, Sleep (sub-state cut off)
  double position = 0;    // the axis as reported (MPos or WPos); GrblTurntable::status() gives WPos
  bool machine = true;    // the report was MPos (else WPos)
  std::optional<double> offset;  // the axis' WCO, in the reports that carry one
};

// "<Idle|MPos:15.000,0.000,0.000|FS:0,0>" or "<Idle|WPos:...|WCO:...>" ->
// state, the axis position and its work offset if reported; other fields
// (Bf, FS, Ov, Pn, ...) in any order are skipped. GRBL 0.9's form (Horus),
// "<Idle,MPos:15.000,0.000,0.000,WPos:15.000,0.000,0.000>", gives WPos.
std::optional<GrblStatus> parse_grbl_status(const std::string& line, char axis = 'X');

// What one line from the board says. Line noise glued to its front ("~#ok")
// is dropped first; anything else ("[MSG:..]", echoes, noise) is kOther.
struct GrblReply {
  enum Kind { kOk, kError, kAlarm, kBanner, kStatus, kOther } kind = kOther;
  int code = -1;       // error:N / ALARM:N; -1 where N is not a number of at most 4 digits
  GrblStatus status;   // kStatus
  std::string text;    // the line without the leading noise
};
GrblReply classify_grbl_reply(const std::string& line, char axis = 'X');
std::string grbl_error_meaning(int code);
std::string grbl_alarm_meaning(int code);

class GrblTurntable : public Turntable {
 public:
  static Result<std::unique_ptr<GrblTurntable>> open(const std::string& port, const GrblOptions& options = {});
  Status home() override;
  Status set_position(double degrees) override;  // G92
  Status move_to(double degrees) override;
  Result<double> position() override;
  std::string describe() const override { return "grbl:" + port_.path() + " (" + banner_ + ")"; }
  Result<GrblStatus> status();  // position in work coordinates

 private:
  GrblTurntable(SerialPort port, GrblOptions o) : port_(std::move(port)), opt_(std::move(o)) {}
  Status wait_banner(std::chrono::milliseconds timeout);
  Status command(const std::string& line);  // waits for ok / error / alarm
  Status check_async(const GrblReply& reply);  // ALARM / reset lines at any time
  Status halted() const;       // the error while the board waits for a reset
  void drain_late_oks();       // before a command: the oks that came after their timeout
  SerialPort port_;
  GrblOptions opt_;
  std::string banner_;
  double wco_ = 0;             // the last work coordinate offset reported
  int late_oks_ = 0;           // commands that timed out and may still be answered
  int halted_alarm_ = 0;       // ALARM code after which the board ignores all but a reset (0: none)
};

}  // namespace s2r
