// Progress on long work: a bar on a terminal, plain log lines otherwise.
#pragma once

#include <cstddef>
#include <mutex>
#include <string>

namespace s2r {

class Progress {
 public:
  Progress(std::string label, size_t total);
  ~Progress();
  void tick(size_t n = 1);  // thread-compatible: call from one thread
  void done();

 private:
  std::string label_;
  size_t total_, count_ = 0;
  int last_percent_ = -1;
  bool tty_;
  bool finished_ = false;
};

// A Progress that worker threads tick at once (parallel loops).
class SharedProgress {
 public:
  SharedProgress(std::string label, size_t total) : bar_(std::move(label), total) {}
  void tick(size_t n = 1) {
    const std::lock_guard<std::mutex> lock(mutex_);
    bar_.tick(n);
  }
  void done() {
    const std::lock_guard<std::mutex> lock(mutex_);
    bar_.done();
  }

 private:
  std::mutex mutex_;
  Progress bar_;
};

// Global switch (tests and --quiet turn progress output off).
void set_progress_enabled(bool enabled);

}  // namespace s2r
