// A serial port over termios: raw 8N1 at a chosen baud rate, line I/O with
// timeouts. Used by the turntable link; tests run it against a pseudo-terminal.
#pragma once

#include <chrono>
#include <functional>
#include <string>

#include "core/result.h"

namespace s2r {

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
  // printable ASCII are dropped (line noise). Errors: timeout ("timed out"),
  // unplug (EIO/ENODEV: "device disconnected"), other errno.
  Result<std::string> read_line(std::chrono::milliseconds timeout);
  // Discard whatever is waiting in both directions.
  void flush();
  const std::string& path() const { return path_; }
  bool timed_out(const Error& e) const { return e.message.find("timed out") != std::string::npos; }

  // Observer of every line in both directions (transcript recording).
  using Tap = std::function<void(char direction, const std::string& line)>;
  void set_tap(Tap tap) { tap_ = std::move(tap); }

 private:
  SerialPort() = default;
  int fd_ = -1;
  std::string path_;
  std::string pending_;  // bytes read past the last line
  Tap tap_;
};

}  // namespace s2r
