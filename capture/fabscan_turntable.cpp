// FabScanPi turntable link and its simulated firmware (capture/fabscan_turntable.h).
#include "capture/fabscan_turntable.h"

#include <poll.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <thread>

#include "capture/pty_device.h"
#include "core/atomic_file.h"

namespace s2r {

namespace {
std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t");
  if (b == std::string::npos) return {};
  return s.substr(b, s.find_last_not_of(" \t") - b + 1);
}
}  // namespace

Result<std::unique_ptr<FabScanTurntable>> FabScanTurntable::open(const std::string& path, const FabScanOptions& o) {
  if (o.steps_per_turn <= 0) return fail(ErrorCode::invalid, "steps_per_turn: must be > 0");
  if (o.feed <= 0) return fail(ErrorCode::invalid, "feed: must be > 0");
  auto port = SerialPort::open(path, o.baud);
  if (!port) return std::unexpected(port.error());
  std::unique_ptr<FabScanTurntable> t(new FabScanTurntable(std::move(*port), o));
  t->port_.set_prompt('>');
  if (!o.transcript.empty()) {
    const auto file = o.transcript;
    t->port_.set_tap([file](char dir, const std::string& line) {
      (void)append_line_durable(file, std::string(1, dir) + " " + line);
    });
  }
  // An Arduino resets when the port opens; whatever it printed before is not ours.
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  t->port_.flush();
  auto v = t->command("M200", o.reply_timeout);
  if (!v) {
    if (v.error().is(ErrorCode::timeout))
      return fail(ErrorCode::timeout, "no FabScan prompt from '" + path + "' after M200 (is it a FabScanPi board at " +
                                          std::to_string(o.baud) + " baud?)");
    return std::unexpected(v.error());
  }
  for (const auto& line : *v)
    if (!line.empty()) t->version_ = line;
  if (t->version_.empty()) t->version_ = "FabScan, version not reported";
  if (auto m = t->command("M17", o.reply_timeout); !m) return std::unexpected(m.error());  // motors on
  return t;
}

Result<std::vector<std::string>> FabScanTurntable::command(const std::string& line, std::chrono::milliseconds timeout) {
  if (auto st = port_.write(line + ";\n"); !st) return std::unexpected(st.error());
  const std::string echo = line + ";";
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::vector<std::string> out;
  for (;;) {
    const auto left = ms_until(deadline);
    if (left.count() <= 0) return fail(ErrorCode::timeout, "no prompt after '" + line + "' from the FabScan board on '" + port_.path() + "'");
    auto got = port_.read_line(left);
    if (!got) {
      if (got.error().is(ErrorCode::timeout))
        return fail(ErrorCode::timeout, "no prompt after '" + line + "' from the FabScan board on '" + port_.path() + "'");
      return std::unexpected(got.error());
    }
    if (*got == ">") return out;
    if (trim(*got) == echo) continue;  // the firmware echoes what it got
    out.push_back(trim(*got));
  }
}

Status FabScanTurntable::home() { return set_position(0); }

Status FabScanTurntable::set_position(double degrees) {
  if (!std::isfinite(degrees)) return fail(ErrorCode::invalid, "turntable position must be finite");
  steps_ = std::llround(degrees * opt_.steps_per_turn / 360.0);
  return {};
}

Status FabScanTurntable::move_to(double degrees) {
  if (!std::isfinite(degrees)) return fail(ErrorCode::invalid, "turntable target must be finite");
  const int64_t target = std::llround(degrees * opt_.steps_per_turn / 360.0);
  const int64_t delta = target - steps_;
  if (delta != 0) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "G04 T%lld F%d", static_cast<long long>(delta), opt_.feed);
    // The prompt comes when the move is done: its time at the feed, plus the reply's.
    const auto move_ms = std::chrono::milliseconds(static_cast<int64_t>(1000.0 * std::abs(double(delta)) / opt_.feed));
    auto r = command(buf, opt_.reply_timeout + 2 * move_ms);
    if (!r) return fail(r.error().code, "turntable move to " + std::to_string(degrees) + " deg: " + r.error().message, r.error().sys_errno);
    steps_ = target;
  }
  std::this_thread::sleep_for(opt_.settle);
  return {};
}

Result<double> FabScanTurntable::position() { return 360.0 * static_cast<double>(steps_) / opt_.steps_per_turn; }

// ---- the simulated firmware ----

Result<std::unique_ptr<FabScanSim>> FabScanSim::start(int steps_per_turn, const FabScanFaults& faults) {
  if (steps_per_turn <= 0) return fail(ErrorCode::invalid, "steps_per_turn: must be > 0");
  std::unique_ptr<FabScanSim> sim(new FabScanSim());
  sim->steps_per_turn_ = steps_per_turn;
  sim->faults_ = faults;
  if (auto st = open_pty(&sim->master_, &sim->slave_, &sim->slave_path_); !st) return std::unexpected(st.error());
  FabScanSim* s = sim.get();
  s->thread_ = std::thread([s] { s->run(); });
  return sim;
}

FabScanSim::~FabScanSim() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (master_ >= 0) ::close(master_);
  if (slave_ >= 0) ::close(slave_);
}

void FabScanSim::unplug() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (slave_ >= 0) ::close(slave_);
  slave_ = -1;
  if (master_ >= 0) ::close(master_);
  master_ = -1;
}

double FabScanSim::position() const {
  std::lock_guard lock(mu_);
  return 360.0 * static_cast<double>(steps_) / steps_per_turn_;
}

bool FabScanSim::motors_on() const {
  std::lock_guard lock(mu_);
  return motors_;
}

int FabScanSim::commands() const {
  std::lock_guard lock(mu_);
  return commands_;
}

void FabScanSim::run() {
  std::string buf;
  while (!stop_) {
    pollfd pfd{master_, POLLIN, 0};
    if (::poll(&pfd, 1, 5) <= 0) continue;
    char tmp[256];
    const ssize_t n = ::read(master_, tmp, sizeof tmp);
    if (n <= 0) continue;
    for (ssize_t i = 0; i < n; ++i) {
      const char c = tmp[i];
      if (faults_.not_fabscan) continue;
      {
        std::lock_guard lock(mu_);
        if (faults_.silent_after >= 0 && commands_ >= faults_.silent_after) continue;
      }
      if (c == '\r') continue;
      write_all(master_, std::string_view(&c, 1));  // the firmware echoes every byte
      if (c != '\n') {
        if (buf.size() < 128) buf.push_back(c);  // MAX_BUF: the rest is dropped
        continue;
      }
      handle(buf);
      buf.clear();
      write_all(master_, ">");
    }
  }
}

void FabScanSim::handle(const std::string& raw) {
  std::string line = raw.substr(0, raw.find(';'));
  auto number = [&](char code, long fallback) {
    // As the firmware's parsenumber: the letter at a word's start, then an integer.
    size_t p = 0;
    while (p < line.size()) {
      if (line[p] == code) return std::strtol(line.c_str() + p + 1, nullptr, 10);
      const size_t sp = line.find(' ', p);
      if (sp == std::string::npos) break;
      p = sp + 1;
    }
    return fallback;
  };
  {
    std::lock_guard lock(mu_);
    ++commands_;
  }
  if (line.empty() || line[0] == ';') return;
  const long g = number('G', -1), m = number('M', -1);
  if (g == 0 || g == 1 || g == 2 || g == 4) {
    const long steps = number('T', 0), feed = std::max(1L, number('F', 0) > 0 ? number('F', 0) : 1000L);
    const double seconds = std::abs(double(steps)) / (feed * faults_.steps_per_second_scale);
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));  // the firmware blocks while it turns
    std::lock_guard lock(mu_);
    if (motors_) steps_ += steps;  // released motors turn nothing
    return;
  }
  if (m == 17 || m == 18) {
    std::lock_guard lock(mu_);
    motors_ = m == 17;
    return;
  }
  if (m == 200) {
    write_all(master_, "v.20240101-sim\r\n");
    return;
  }
  // M19-M22 lasers, M05 light ring, M114, unknown: nothing to say.
}

}  // namespace s2r
