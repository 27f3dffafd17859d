#include "capture/grbl_sim.h"

#include "capture/pty_device.h"

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <regex>

namespace s2r {

namespace {
double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
constexpr const char* kBanner = "\r\nGrbl 1.1h ['$' for help]\r\n";
constexpr const char* kHorusBanner = "\r\nHorus 0.1 ['$' for help]\r\n";
}  // namespace

Result<std::unique_ptr<GrblSim>> GrblSim::start(const GrblFaults& faults) {
  std::unique_ptr<GrblSim> sim(new GrblSim());
  sim->faults_ = faults;
  sim->alarm_ = faults.start_in_alarm || faults.homing_enabled;
  sim->mask_ = faults.status_mask;
  sim->motor_on_ = !faults.horus;
  GrblSim* s = sim.get();
  if (auto st = open_pty(&s->master_, &s->slave_, &s->slave_path_); !st) return std::unexpected(st.error());
  if (!faults.no_banner)
    s->reply(std::string(faults.horus ? kHorusBanner : kBanner) + (s->alarm_ ? "[MSG:'$H'|'$X' to unlock]\r\n" : ""));
  s->thread_ = std::thread([s] { s->run(); });
  return sim;
}

Result<std::unique_ptr<GrblSim>> GrblSim::replay(const std::filesystem::path& transcript) {
  std::ifstream in(transcript);
  if (!in) return fail("'" + transcript.string() + "': cannot open transcript");
  std::unique_ptr<GrblSim> sim(new GrblSim());
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (line.size() < 2 || (line[0] != '>' && line[0] != '<') || line[1] != ' ')
      return fail("'" + transcript.string() + "': line " + std::to_string(n) + ": expected '> ' or '< '");
    sim->transcript_.emplace_back(line[0], line.substr(2));
  }
  sim->replaying_ = true;
  GrblSim* s = sim.get();
  if (auto st = open_pty(&s->master_, &s->slave_, &s->slave_path_); !st) return std::unexpected(st.error());
  // Device lines before the first host line (the banner) go out at once.
  size_t i = 0;
  for (; i < s->transcript_.size() && s->transcript_[i].first == '<'; ++i) s->reply(s->transcript_[i].second + "\r\n");
  s->transcript_.erase(s->transcript_.begin(), s->transcript_.begin() + static_cast<long>(i));
  s->thread_ = std::thread([s] { s->run_replay(); });
  return sim;
}

GrblSim::~GrblSim() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (master_ >= 0) ::close(master_);
  if (slave_ >= 0) ::close(slave_);
}

void GrblSim::unplug() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (slave_ >= 0) ::close(slave_);
  slave_ = -1;
  if (master_ >= 0) ::close(master_);
  master_ = -1;
}

void GrblSim::reply(const std::string& text) { write_all(master_, text); }

double GrblSim::position_locked() const {
  const double t = now_s();
  if (t >= move_end_ || move_end_ <= move_start_) return to_;
  return from_ + (to_ - from_) * (t - move_start_) / (move_end_ - move_start_);
}

double GrblSim::position() const {
  std::lock_guard lock(mu_);
  return position_locked() - wco_;
}

double GrblSim::table_angle() const {
  std::lock_guard lock(mu_);
  return position_locked() - wco_ - table_offset_;
}

double GrblSim::machine_position() const {
  std::lock_guard lock(mu_);
  return position_locked();
}

std::string GrblSim::status_line() {
  const double p = position_locked();
  const bool moving = now_s() < move_end_;
  const char* state = alarm_ ? "Alarm" : moving ? "Run" : "Idle";
  char buf[256];
  if (faults_.horus) {  // GRBL 0.9's report
    std::snprintf(buf, sizeof buf, "<%s,MPos:%.3f,0.000,0.000,WPos:%.3f,0.000,0.000>\r\n", state, p, p - wco_);
    return buf;
  }
  int n = std::snprintf(buf, sizeof buf, "<%s|%s:%.3f,0.000,0.000", state, (mask_ & 1) ? "MPos" : "WPos",
                        (mask_ & 1) ? p : p - wco_);
  if (mask_ & 2) n += std::snprintf(buf + n, sizeof buf - n, "|Bf:15,128");
  n += std::snprintf(buf + n, sizeof buf - n, "|FS:0,0");
  if (limit_pin_) n += std::snprintf(buf + n, sizeof buf - n, "|Pn:X");
  ++reports_;
  --ov_countdown_;
  if (wco_due_ || reports_ % (moving ? 10 : 30) == 0) {
    n += std::snprintf(buf + n, sizeof buf - n, "|WCO:%.3f,0.000,0.000", wco_);
    wco_due_ = false;
    if (ov_countdown_ <= 0) ov_countdown_ = 1;  // Ov waits a report when WCO is sent
  } else if (ov_countdown_ <= 0) {
    n += std::snprintf(buf + n, sizeof buf - n, "|Ov:100,100,100");
    ov_countdown_ = 20;
  }
  std::snprintf(buf + n, sizeof buf - n, ">\r\n");
  return buf;
}

void GrblSim::forget_offsets() {
  wco_ = 0;  // G92 offsets do not survive a reset
  wco_due_ = true;  // WCO in the first report after it, Ov in the second
  reports_ = 0;
  ov_countdown_ = 2;
}

void GrblSim::soft_reset() {
  const double t = now_s();
  if (t < move_end_) {  // a reset in motion loses the position: ALARM:3, then Alarm
    to_ = from_ = 0;
    alarm_ = true;
    reply("ALARM:3\r\n");
  } else {
    from_ = to_ = position_locked();
  }
  move_end_ = move_start_ = 0;
  if (locked_) alarm_ = true;  // after a limit alarm the board comes back in Alarm
  if (faults_.homing_enabled) alarm_ = true;
  locked_ = false;
  hard_limit_time_ = -1;
  forget_offsets();
  pending_lines_.clear();
  late_replies_.clear();
  reply(std::string(faults_.horus ? kHorusBanner : kBanner) + (alarm_ ? "[MSG:'$H'|'$X' to unlock]\r\n" : ""));
}

void GrblSim::limit_alarm(int code) {
  // GRBL's critical event: motion stops where it is and the board is deaf
  // until a soft reset.
  from_ = to_ = position_locked();
  move_end_ = move_start_ = 0;
  alarm_ = locked_ = true;
  pending_lines_.clear();
  late_replies_.clear();
  reply("ALARM:" + std::to_string(code) + "\r\n[MSG:Reset to continue]\r\n");
}

void GrblSim::run_due(double t) {
  if (reset_at_line_ >= 0 && t >= 0.5 * (move_start_ + move_end_)) {  // reset halfway
    to_ = from_ = 0;  // a reset board knows no position
    move_end_ = move_start_ = 0;
    reset_at_line_ = -1;
    forget_offsets();
    reply("ALARM:3\r\n" + std::string(kBanner));
  }
  if (hard_limit_time_ >= 0 && t >= hard_limit_time_) {
    hard_limit_time_ = -1;
    limit_pin_ = true;
    limit_alarm(1);
  }
  for (size_t i = 0; i < late_replies_.size();)
    if (t >= late_replies_[i].first) {
      reply(late_replies_[i].second);
      late_replies_.erase(late_replies_.begin() + static_cast<long>(i));
    } else {
      ++i;
    }
  while (!pending_lines_.empty() && t >= pending_lines_.front().first && !locked_) {
    const std::string line = pending_lines_.front().second;
    pending_lines_.erase(pending_lines_.begin());
    handle_line(line);
  }
}

void GrblSim::handle_line(const std::string& raw) {
  std::string line;
  for (char c : raw)
    if (c != ' ') line.push_back(static_cast<char>(std::toupper(static_cast<unsigned char>(c))));
  if (line.empty()) {  // GRBL answers an empty line "ok" (hosts use it to sync)
    reply("ok\r\n");
    return;
  }
  const int index = gcode_index_++;
  lines_++;
  if (faults_.silent_after >= 0 && index >= faults_.silent_after) {
    silent_ = true;
    return;
  }
  std::string out;
  if (faults_.garbage_every > 0 && ++replies_ % faults_.garbage_every == 0) out += "\x01\xfe~#\x7f\r\n#~";  // a line of noise, then noise before the reply
  if (index == faults_.error_at) {
    reply(out + "error:20\r\n");
    return;
  }
  if (line == "$X") {
    alarm_ = false;
    limit_pin_ = false;
    reply(out + "[MSG:Caution: Unlocked]\r\nok\r\n");
    return;
  }
  if (line.rfind("$10=", 0) == 0) {
    mask_ = std::atoi(line.c_str() + 4);
    reply(out + "ok\r\n");
    return;
  }
  if (line == "$H") {
    if (!faults_.homing_enabled) {
      reply(out + "error:5\r\n");  // homing is not enabled in settings
      return;
    }
    from_ = to_ = 0;
    move_end_ = move_start_ = 0;
    alarm_ = limit_pin_ = false;
    reply(out + "ok\r\n");
    return;
  }
  if (alarm_) {
    reply(out + "error:9\r\n");
    return;
  }
  if (faults_.horus) {
    if (line == "M17" || line == "M18") {
      motor_on_ = line == "M17";
      reply(out + "ok\r\n");
      return;
    }
    if ((line.rfind("M70", 0) == 0 || line.rfind("M71", 0) == 0) && line.size() > 4 && line[3] == 'T') {
      reply(out + "ok\r\n");  // lasers off / on
      return;
    }
    if (line == "G50") {  // the current angle becomes 0
      from_ = to_ = position_locked();
      move_end_ = move_start_ = 0;
      wco_ = to_;
      reply(out + "ok\r\n");
      return;
    }
  }
  if (line.rfind("G92", 0) == 0) {  // declare the current position: a work offset, the motor stays
    const size_t xp = line.find('X');
    const double v = xp == std::string::npos ? 0.0 : std::strtod(line.c_str() + xp + 1, nullptr);
    // G92 syncs the planner: the offset applies to where the table stops.
    from_ = to_ = position_locked();
    move_end_ = move_start_ = 0;
    wco_ = to_ - (std::isfinite(v) ? v : 0.0);
    wco_due_ = true;
    reply(out + "ok\r\n");
    return;
  }
  // Motion: G90/G91 modal, G0/G1 with an X word.
  if (line.find("G91") != std::string::npos) absolute_ = false;
  if (line.find("G90") != std::string::npos) absolute_ = true;
  const size_t x = line.find('X');
  if (x != std::string::npos) {
    char* end = nullptr;
    const double v = std::strtod(line.c_str() + x + 1, &end);
    if (end == line.c_str() + x + 1 || !std::isfinite(v)) {
      reply(out + "error:2\r\n");
      return;
    }
    if (index == faults_.alarm_at) {  // soft limit: the target is past the travel
      reply(out);
      limit_alarm(2);
      return;
    }
    const double start = position_locked();
    from_ = start;
    to_ = absolute_ ? v + wco_ : start + v;
    move_start_ = now_s();
    double speed = faults_.degrees_per_second;
    if (faults_.horus) {
      const size_t f = line.find('F');
      if (f != std::string::npos) {
        const double feed = std::strtod(line.c_str() + f + 1, nullptr);  // deg/min
        if (std::isfinite(feed) && feed > 0) speed = std::min(speed, feed / 60.0 * 20);  // the simulated table: 20x the feed
      }
      if (!motor_on_) table_offset_ += to_ - from_;  // steps counted, the table stands
    }
    move_end_ = move_start_ + std::abs(to_ - from_) / speed;
    if (index == faults_.reset_mid_move_at) reset_at_line_ = index;
    if (index == faults_.hard_limit_at) hard_limit_time_ = 0.5 * (move_start_ + move_end_);
  } else if (line.find_first_not_of("G0123456789.") != std::string::npos && line[0] != '$') {
    reply(out + "error:20\r\n");
    return;
  }
  if (index == faults_.drop_ok_at) return;
  if (index == faults_.late_ok_at) {
    reply(out);
    late_replies_.push_back({now_s() + faults_.late_ok_ms / 1000.0, "ok\r\n"});
    return;
  }
  reply(out + "ok\r\n");
}

void GrblSim::run() {
  std::string buf;
  while (!stop_) {
    pollfd pfd{master_, POLLIN, 0};
    if (::poll(&pfd, 1, 2) <= 0) {
      std::lock_guard lock(mu_);
      run_due(now_s());
      continue;
    }
    char tmp[256];
    ssize_t n = ::read(master_, tmp, sizeof tmp);
    if (n <= 0) continue;
    std::lock_guard lock(mu_);
    run_due(now_s());
    for (ssize_t i = 0; i < n; ++i) {
      const char c = tmp[i];
      if (silent_) continue;
      if (c == 0x18) {  // soft reset: the only thing a locked board hears
        buf.clear();
        soft_reset();
      } else if (locked_) {
        continue;
      } else if (c == '?') {  // real-time: answered before lines waiting to be parsed
        reply(status_line());
      } else if (c == '\n' || c == '\r') {
        if (faults_.parse_latency_ms > 0)
          pending_lines_.push_back({now_s() + faults_.parse_latency_ms / 1000.0, buf});
        else
          handle_line(buf);
        buf.clear();
      } else {
        buf.push_back(c);
      }
    }
  }
}

void GrblSim::run_replay() {
  std::string buf;
  size_t next = 0;
  std::string last_status = "<Idle|MPos:0.000,0.000,0.000|FS:0,0>";
  auto send_replies = [&] {
    while (next < transcript_.size() && transcript_[next].first == '<') {
      const std::string& l = transcript_[next++].second;
      if (!l.empty() && l.front() == '<') last_status = l;
      reply(l + "\r\n");
    }
  };
  // Status polls depend on timing: their count need not match the recording.
  auto answer = [&](const std::string& host) {
    if (host != "?")
      while (next < transcript_.size() && transcript_[next].first == '>' && transcript_[next].second == "?") {
        ++next;
        while (next < transcript_.size() && transcript_[next].first == '<') {
          if (!transcript_[next].second.empty() && transcript_[next].second.front() == '<')
            last_status = transcript_[next].second;
          ++next;
        }
      }
    if (next < transcript_.size() && transcript_[next].first == '>' && transcript_[next].second == host) {
      ++next;
      send_replies();
    } else if (host == "?") {
      reply(last_status + "\r\n");
    }
  };
  while (!stop_) {
    pollfd pfd{master_, POLLIN, 0};
    if (::poll(&pfd, 1, 5) <= 0) continue;
    char tmp[256];
    ssize_t n = ::read(master_, tmp, sizeof tmp);
    if (n <= 0) continue;
    for (ssize_t i = 0; i < n; ++i) {
      const char c = tmp[i];
      if (c == '?' || c == 0x18) {
        answer(std::string(1, c));
      } else if (c == '\n' || c == '\r') {
        if (!buf.empty()) answer(buf);
        lines_++;
        buf.clear();
      } else {
        buf.push_back(c);
      }
    }
  }
}

}  // namespace s2r
