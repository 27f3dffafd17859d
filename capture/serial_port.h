// A serial port over termios: raw 8N1 at a chosen baud rate, line I/O with
// timeouts. Used by the turntable link; tests run it against a pseudo-terminal.
#pragma once

#include <chrono>
#include <cstddef>
#include <deque>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "core/result.h"

namespace s2r {

// Whole milliseconds left until a deadline on the steady clock (<= 0: passed).
inline std::chrono::milliseconds ms_until(std::chrono::steady_clock::time_point deadline) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
}

// Splits a serial byte stream into lines. "\r\n", "\n" and a lone "\r" each
// end a line; bytes that are not printable ASCII are dropped (line noise). A
// line longer than `max_line` bytes is cut there and counted, so a device that
// never sends a terminator cannot grow memory.
class LineSplitter {
 public:
  explicit LineSplitter(size_t max_line = 1024) : max_line_(max_line > 0 ? max_line : 1) {}
  void feed(std::string_view bytes);
  std::optional<std::string> next();  // the oldest complete line, if any
  void clear();
  size_t cut_lines() const { return cut_; }
  // A device that prints a prompt with no line end after it (FabScan's ">"
  // once a command is done): that character alone at the start of a line
  // is a line of its own. 0: none.
  void set_prompt(char prompt) { prompt_ = prompt; }

 private:
  size_t max_line_;
  char prompt_ = 0;
  std::string partial_;
  std::deque<std::string> lines_;
  bool after_cr_ = false;
  size_t cut_ = 0;
};

class SerialPort {
 public:
  // Opens and configures `path` (raw, 8N1, no flow control, `baud`).
  static Result<SerialPort> open(const std::string& path, int baud);
  SerialPort(SerialPort&& o) noexcept;
  SerialPort& operator=(SerialPort&& o) noexcept;
  SerialPort(const SerialPort&) = delete;
  ~SerialPort();

  Status write(std::string_view bytes);
  // One line without its terminator ("\r\n" or "\n"). Bytes that are not
  // printable ASCII are dropped (line noise). Errors: ErrorCode::timeout,
  // ErrorCode::disconnected (EIO/ENODEV/ENXIO), otherwise io with the errno.
  Result<std::string> read_line(std::chrono::milliseconds timeout);
  // Discard whatever is waiting in both directions.
  void flush();
  const std::string& path() const { return path_; }

  // Observer of every line in both directions (transcript recording).
  using Tap = std::function<void(char direction, const std::string& line)>;
  void set_tap(Tap tap) { tap_ = std::move(tap); }
  // See LineSplitter::set_prompt.
  void set_prompt(char prompt) { lines_.set_prompt(prompt); }

 private:
  SerialPort() = default;
  int fd_ = -1;
  std::string path_;
  LineSplitter lines_;
  Tap tap_;
};

}  // namespace s2r
