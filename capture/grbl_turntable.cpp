#include "capture/grbl_turntable.h"

#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <thread>

#include "core/atomic_file.h"

namespace s2r {
using namespace std::chrono_literals;

std::string grbl_error_meaning(int code) {
  if (code < 0) return "unreadable error code";
  switch (code) {
    case 1: return "G-code words consist of a letter and a value; letter was not found";
    case 2: return "numeric value format is not valid or missing an expected value";
    case 3: return "'$' system command was not recognized or supported";
    case 8: return "command only valid when idle";
    case 9: return "G-code locked out during alarm or jog state (unlock with $X)";
    case 15: return "jog target exceeds machine travel";
    case 20: return "unsupported or invalid G-code command";
    case 22: return "feed rate has not yet been set or is undefined";
    case 33: return "motion command has an invalid target";
    default: return "GRBL error code " + std::to_string(code);
  }
}

std::string grbl_alarm_meaning(int code) {
  if (code < 0) return "unreadable alarm code";
  switch (code) {
    case 1: return "hard limit triggered; position is likely lost, re-home";
    case 2: return "soft limit: motion target exceeds machine travel";
    case 3: return "reset while in motion; position is likely lost, re-home";
    case 4: return "probe fail";
    case 6: case 7: case 8: case 9: return "homing failed";
    default: return "GRBL alarm code " + std::to_string(code);
  }
}

std::optional<GrblStatus> parse_grbl_status(const std::string& line, char axis) {
  if (line.size() < 3 || line.front() != '<' || line.back() != '>') return std::nullopt;
  const std::string body = line.substr(1, line.size() - 2);
  GrblStatus s;
  const int index = axis == 'X' ? 0 : axis == 'Y' ? 1 : axis == 'Z' ? 2 : 3;
  if (body.find('|') == std::string::npos && body.find(',') < body.find(':')) {
    // GRBL 0.9 (Horus): "Idle,MPos:x,y,z,WPos:x,y,z[,Buf:..]": the work position.
    s.state = body.substr(0, body.find(','));
    const size_t w = body.find(",WPos:");
    if (s.state.empty() || w == std::string::npos) return std::nullopt;
    size_t p = w + 6;
    for (int i = 0; i < index; ++i) {
      p = body.find(',', p);
      if (p == std::string::npos) return std::nullopt;
      ++p;
    }
    char* end = nullptr;
    const double v = std::strtod(body.c_str() + p, &end);
    if (end == body.c_str() + p || !std::isfinite(v)) return std::nullopt;
    s.position = v;
    s.machine = false;
    return s;
  }
  s.state = body.substr(0, body.find_first_of("|:"));
  if (s.state.empty()) return std::nullopt;
  // The axis' value in a field "NAME:x,y,z[,a]" (fields are '|'-separated, in any order).
  auto field = [&](const char* name) -> std::optional<std::optional<double>> {
    const std::string key = std::string("|") + name + ":";
    const size_t m = body.find(key);
    if (m == std::string::npos) return std::nullopt;
    const size_t stop = std::min(body.find('|', m + 1), body.size());
    size_t p = m + key.size();
    for (int i = 0; i < index; ++i) {
      p = body.find(',', p);
      if (p == std::string::npos || p >= stop) return std::optional<double>();
      ++p;
    }
    char* end = nullptr;
    const double v = std::strtod(body.c_str() + p, &end);
    if (end == body.c_str() + p || end > body.c_str() + stop || !std::isfinite(v)) return std::optional<double>();
    return std::optional<double>(v);
  };
  auto mpos = field("MPos");
  auto wpos = field("WPos");
  if (mpos.has_value() == wpos.has_value()) return std::nullopt;  // exactly one of them
  const auto& pos = mpos ? *mpos : *wpos;
  if (!pos) return std::nullopt;
  s.position = *pos;
  s.machine = mpos.has_value();
  if (auto wco = field("WCO")) {
    if (!*wco) return std::nullopt;
    s.offset = **wco;
  }
  return s;
}

Result<std::unique_ptr<GrblTurntable>> GrblTurntable::open(const std::string& path, const GrblOptions& o) {
  auto port = SerialPort::open(path, o.baud);
  if (!port) return std::unexpected(port.error());
  std::unique_ptr<GrblTurntable> t(new GrblTurntable(std::move(*port), o));
  if (!o.transcript.empty()) {
    const auto file = o.transcript;
    t->port_.set_tap([file](char dir, const std::string& line) {
      (void)append_line_durable(file, std::string(1, dir) + " " + line);
    });
  }
  // The board resets when the port opens: wait for its banner; else ask for one.
  if (auto st = t->wait_banner(o.banner_timeout); !st) {
    if (auto w = t->port_.write("\x18"); !w) return std::unexpected(w.error());
    if (auto st2 = t->wait_banner(o.banner_timeout); !st2)
      return fail(st2.error().code, "no GRBL banner from '" + path + "' after a soft reset (is it a GRBL board at " +
                  std::to_string(o.baud) + " baud?): " + st2.error().message, st2.error().sys_errno);
  }
  if (o.dialect != "grbl" && o.dialect != "horus")
    return fail(ErrorCode::invalid, "dialect: '" + o.dialect + "' (grbl or horus)");
  auto s = t->status();
  if (!s) return std::unexpected(s.error());
  if (o.dialect == "horus") {
    // Horus boards start with the motor released: on, or the table would not turn.
    if (auto st = t->command("M17"); !st) return std::unexpected(st.error());
  }
  if (s->state == "Alarm") {
    if (!o.unlock_alarm)
      return fail(ErrorCode::device_fault,
                  "turntable on '" + path + "' starts in alarm state; check it, then unlock it (unlock_alarm sends $X)");
    if (auto st = t->command("$X"); !st) return std::unexpected(st.error());
  }
  return t;
}

Status GrblTurntable::wait_banner(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    const auto left = ms_until(deadline);
    if (left.count() <= 0) return fail(ErrorCode::timeout, "timed out waiting for the banner");
    auto line = port_.read_line(left);
    if (!line) return std::unexpected(line.error());
    if (const GrblReply r = classify_grbl_reply(*line); r.kind == GrblReply::kBanner) {
      banner_ = r.text;
      return {};
    }
  }
}

Status GrblTurntable::check_async(const GrblReply& r) {
  if (r.kind == GrblReply::kAlarm) {
    // Limit alarms are GRBL's critical events: "[MSG:Reset to continue]"
    // follows and the board hears nothing but a reset.
    if (r.code == 1 || r.code == 2) halted_alarm_ = r.code;
    return fail(ErrorCode::device_fault, "turntable alarm " + std::to_string(r.code) + ": " + grbl_alarm_meaning(r.code));
  }
  if (r.kind == GrblReply::kBanner) {
    wco_ = 0;  // a reset clears G92
    halted_alarm_ = 0;
    return fail(ErrorCode::device_fault,
                "turntable reset itself (" + r.text + "): its position is lost; check power and cabling, "
                "then resume (the table is re-homed at the current position)");
  }
  if (r.text == "[MSG:Reset to continue]") {
    if (halted_alarm_ == 0) halted_alarm_ = -1;
    return halted();
  }
  return {};
}

Status GrblTurntable::halted() const {
  const std::string what = halted_alarm_ > 0 ? "alarm " + std::to_string(halted_alarm_) + " (" +
                                                   grbl_alarm_meaning(halted_alarm_) + ")"
                                             : "a limit alarm";
  return fail(ErrorCode::device_fault,
              "turntable on '" + port_.path() + "' halted after " + what +
                  ": GRBL ignores every command until it is reset; check the table, then reopen it (opening the "
                  "port resets the board) and home it again");
}

void GrblTurntable::drain_late_oks() {
  const auto deadline = std::chrono::steady_clock::now() + opt_.reply_timeout;
  while (late_oks_ > 0) {
    const auto left = ms_until(deadline);
    if (left.count() <= 0) break;
    auto line = port_.read_line(left);
    if (!line) break;
    if (classify_grbl_reply(*line, opt_.axis[0]).kind == GrblReply::kOk) --late_oks_;
  }
  late_oks_ = 0;  // what did not come by now was lost, not late
}

namespace {
// "error:9" -> 9; -1 unless 1 to 4 digits follow the prefix.
int reply_code(const std::string& text, size_t prefix) {
  const size_t n = text.size() - prefix;
  if (n < 1 || n > 4) return -1;
  int code = 0;
  for (size_t i = prefix; i < text.size(); ++i) {
    if (!std::isdigit(static_cast<unsigned char>(text[i]))) return -1;
    code = code * 10 + (text[i] - '0');
  }
  return code;
}
}  // namespace

GrblReply classify_grbl_reply(const std::string& line, char axis) {
  GrblReply r;
  size_t i = 0;
  while (i < line.size() && !std::isalnum(static_cast<unsigned char>(line[i])) && line[i] != '<' && line[i] != '[') ++i;
  r.text = line.substr(i);
  if (r.text == "ok") {
    r.kind = GrblReply::kOk;
  } else if (r.text.rfind("error:", 0) == 0) {
    r.kind = GrblReply::kError;
    r.code = reply_code(r.text, 6);
  } else if (r.text.rfind("ALARM:", 0) == 0) {
    r.kind = GrblReply::kAlarm;
    r.code = reply_code(r.text, 6);
  } else if (r.text.rfind("Grbl", 0) == 0 || r.text.rfind("Horus", 0) == 0) {
    r.kind = GrblReply::kBanner;
  } else if (auto st = parse_grbl_status(r.text, axis)) {
    r.kind = GrblReply::kStatus;
    r.status = *st;
  }
  return r;
}

Status GrblTurntable::command(const std::string& cmd) {
  if (halted_alarm_ != 0) return halted();
  // GRBL's replies carry no sequence number: an "ok" that came after its
  // command's timeout would otherwise be taken as the reply to this one.
  if (late_oks_ > 0) drain_late_oks();
  if (auto st = port_.write(cmd + "\n"); !st) return st;
  for (;;) {
    auto line = port_.read_line(opt_.reply_timeout);
    if (!line) {
      if (line.error().is(ErrorCode::timeout)) {
        ++late_oks_;
        return fail(ErrorCode::timeout, "no reply to '" + cmd + "' (lost ok?)");
      }
      return std::unexpected(line.error());
    }
    const GrblReply r = classify_grbl_reply(*line, opt_.axis[0]);
    if (r.kind == GrblReply::kOk) return {};
    if (r.kind == GrblReply::kError)
      return fail(ErrorCode::protocol,
                  "turntable rejected '" + cmd + "': " + r.text + " (" + grbl_error_meaning(r.code) + ")");
    if (auto st = check_async(r); !st) return st;
    // "[MSG:...]", status reports, echoes and noise: keep waiting.
  }
}

Result<GrblStatus> GrblTurntable::status() {
  if (halted_alarm_ != 0) return std::unexpected(halted().error());
  int unanswered = 0;
  for (;;) {
    if (auto st = port_.write("?"); !st) return std::unexpected(st.error());
    const auto deadline = std::chrono::steady_clock::now() + opt_.reply_timeout;
    bool timed_out = false;
    while (!timed_out) {
      const auto left = ms_until(deadline);
      if (left.count() <= 0) break;
      auto line = port_.read_line(left);
      if (!line) {
        if (!line.error().is(ErrorCode::timeout)) return std::unexpected(line.error());
        timed_out = true;
        break;
      }
      GrblReply r = classify_grbl_reply(*line, opt_.axis[0]);
      if (auto st = check_async(r); !st) return std::unexpected(st.error());
      if (r.kind == GrblReply::kOk && late_oks_ > 0) --late_oks_;
      if (r.kind == GrblReply::kStatus) {
        GrblStatus s = r.status;
        if (s.offset) wco_ = *s.offset;
        if (s.machine) s.position -= wco_;
        s.machine = false;
        return s;
      }
    }
    if (++unanswered > opt_.retries)
      return fail(ErrorCode::timeout, "turntable on '" + port_.path() + "' is silent: " + std::to_string(unanswered) +
                  " status requests unanswered");
  }
}

Status GrblTurntable::home() {
  // DIY turntables rarely have a homing switch: the current position becomes 0
  // (Horus: G50, its origin reset, as its host software sends it).
  if (opt_.dialect == "horus") return command("G50");
  return set_position(0);
}

Status GrblTurntable::set_position(double degrees) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "G92 %s%.4f", opt_.axis.c_str(), degrees);
  return command(buf);
}

Status GrblTurntable::move_to(double degrees) {
  char buf[64];
  if (opt_.dialect == "horus")
    std::snprintf(buf, sizeof buf, "G1 %s%.4f F%.1f", opt_.axis.c_str(), degrees, opt_.feed_deg_per_min);
  else
    std::snprintf(buf, sizeof buf, "G90 G0 %s%.4f", opt_.axis.c_str(), degrees);
  if (auto st = command(buf); !st) {
    // A lost "ok" is not fatal: the status poll below tells where the table is.
    if (!st.error().is(ErrorCode::timeout)) return st;
  }
  const auto deadline = std::chrono::steady_clock::now() + opt_.move_timeout;
  for (;;) {
    auto s = status();
    if (!s) return std::unexpected(s.error());
    if (s->state == "Alarm")
      return fail(ErrorCode::device_fault, "turntable entered alarm state during the move to " + std::to_string(degrees) + " deg");
    if (s->state == "Idle") {
      if (std::abs(s->position - degrees) > 0.01) {
        // The command was lost before the board took it: send it again (absolute, so safe).
        if (auto st = command(buf); !st) return st;
        continue;
      }
      std::this_thread::sleep_for(opt_.settle);
      return {};
    }
    if (std::chrono::steady_clock::now() > deadline)
      return fail(ErrorCode::timeout, "turntable did not reach " + std::to_string(degrees) + " deg within " +
                  std::to_string(opt_.move_timeout.count() / 1000) + " s (state " + s->state + ")");
    std::this_thread::sleep_for(opt_.poll_interval);
  }
}

Result<double> GrblTurntable::position() {
  auto s = status();
  if (!s) return std::unexpected(s.error());
  return s->position;
}

}  // namespace s2r
