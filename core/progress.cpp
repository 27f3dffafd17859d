#include "core/progress.h"

#include <unistd.h>

#include <cstdio>

namespace s2r {

namespace {
bool g_enabled = true;
}

void set_progress_enabled(bool enabled) { g_enabled = enabled; }

Progress::Progress(std::string label, size_t total)
    : label_(std::move(label)), total_(total ? total : 1), tty_(::isatty(STDERR_FILENO) == 1) {}

Progress::~Progress() { done(); }

void Progress::tick(size_t n) {
  count_ += n;
  if (!g_enabled) return;
  int percent = static_cast<int>(100.0 * double(count_) / double(total_));
  if (percent > 100) percent = 100;
  if (tty_) {
    if (percent == last_percent_) return;
    const int width = 30, filled = percent * width / 100;
    std::fprintf(stderr, "\r%-20s [%.*s%*s] %3d%% (%zu/%zu)", label_.c_str(), filled,
                 "##############################", width - filled, "", percent, count_, total_);
    std::fflush(stderr);
  } else if (percent / 10 != last_percent_ / 10 || count_ == total_) {
    std::fprintf(stderr, "%s: %zu/%zu (%d%%)\n", label_.c_str(), count_, total_, percent);
  }
  last_percent_ = percent;
}

void Progress::done() {
  if (finished_) return;
  finished_ = true;
  if (g_enabled && tty_ && last_percent_ >= 0) std::fprintf(stderr, "\n");
}

}  // namespace s2r
