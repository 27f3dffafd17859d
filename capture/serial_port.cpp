#include "capture/serial_port.h"

#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <utility>

namespace s2r {

namespace {

speed_t baud_constant(int baud) {
  switch (baud) {
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    case 250000: return B230400;  // not a POSIX constant; nearest standard
    default: return 0;
  }
}

// A failed system call on `path`: its errno kept, a disconnect said as such.
std::unexpected<Error> fail_errno(const std::string& prefix, const std::string& path, int err) {
  const ErrorCode code = code_for_errno(err);
  if (code == ErrorCode::disconnected)
    return fail(code, prefix + "'" + path + "': device disconnected (" + std::strerror(err) + ")", err);
  return fail(code, prefix + "'" + path + "': " + std::strerror(err), err);
}

}  // namespace

Result<SerialPort> SerialPort::open(const std::string& path, int baud) {
  const speed_t speed = baud_constant(baud);
  if (!speed) return fail(ErrorCode::unsupported, "unsupported baud rate " + std::to_string(baud));
  SerialPort p;
  p.path_ = path;
  p.fd_ = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (p.fd_ < 0) return fail_errno("cannot open serial port ", path, errno);
  termios tio{};
  if (tcgetattr(p.fd_, &tio) != 0) return fail(ErrorCode::unsupported, "'" + path + "' is not a serial port: " + std::strerror(errno), errno);
  cfmakeraw(&tio);
  tio.c_cflag &= ~static_cast<tcflag_t>(CSTOPB | PARENB | CRTSCTS);
  tio.c_cflag |= CS8 | CLOCAL | CREAD;
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  cfsetispeed(&tio, speed);
  cfsetospeed(&tio, speed);
  if (tcsetattr(p.fd_, TCSANOW, &tio) != 0) return fail(ErrorCode::io, "cannot configure '" + path + "': " + std::strerror(errno), errno);
  return p;
}

SerialPort::SerialPort(SerialPort&& o) noexcept { *this = std::move(o); }
SerialPort& SerialPort::operator=(SerialPort&& o) noexcept {
  std::swap(fd_, o.fd_);
  std::swap(path_, o.path_);
  std::swap(lines_, o.lines_);
  std::swap(tap_, o.tap_);
  return *this;
}
SerialPort::~SerialPort() {
  if (fd_ >= 0) ::close(fd_);
}

Status SerialPort::write(std::string_view bytes) {
  if (tap_) {
    std::string shown(bytes);
    while (!shown.empty() && (shown.back() == '\n' || shown.back() == '\r')) shown.pop_back();
    tap_('>', shown);
  }
  size_t done = 0;
  while (done < bytes.size()) {
    ssize_t n = ::write(fd_, bytes.data() + done, bytes.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN) {
        pollfd pfd{fd_, POLLOUT, 0};
        if (::poll(&pfd, 1, 1000) <= 0) return fail(ErrorCode::timeout, "'" + path_ + "': write timed out");
        continue;
      }
      return fail_errno("", path_, errno);
    }
    done += static_cast<size_t>(n);
  }
  return {};
}

Result<std::string> SerialPort::read_line(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (auto line = lines_.next()) {
      if (tap_) tap_('<', *line);
      return std::move(*line);
    }
    const auto left = ms_until(deadline);
    if (left.count() <= 0) return fail(ErrorCode::timeout, "'" + path_ + "': timed out waiting for a reply");
    pollfd pfd{fd_, POLLIN, 0};
    int r = ::poll(&pfd, 1, static_cast<int>(left.count()));
    if (r < 0) {
      if (errno == EINTR) continue;
      return fail_errno("", path_, errno);
    }
    if (r == 0) continue;
    if (pfd.revents & (POLLHUP | POLLERR | POLLNVAL)) {
      char probe;
      if (::read(fd_, &probe, 1) <= 0) return fail_errno("", path_, errno ? errno : EIO);
    }
    char buf[256];
    ssize_t n = ::read(fd_, buf, sizeof buf);
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      return fail_errno("", path_, errno);
    }
    if (n == 0) return fail_errno("", path_, EIO);
    lines_.feed(std::string_view(buf, static_cast<size_t>(n)));
  }
}

void LineSplitter::feed(std::string_view bytes) {
  for (const char ch : bytes) {
    const unsigned char c = static_cast<unsigned char>(ch);
    if (c == '\n' && after_cr_) {  // the second half of "\r\n"
      after_cr_ = false;
      continue;
    }
    after_cr_ = c == '\r';
    if (c == '\n' || c == '\r') {
      lines_.push_back(std::move(partial_));
      partial_.clear();
      continue;
    }
    if (c < 0x20 || c >= 0x7f) continue;
    if (partial_.size() >= max_line_) {
      lines_.push_back(std::move(partial_));
      partial_.clear();
      ++cut_;
    }
    partial_.push_back(ch);
    if (prompt_ != 0 && partial_.size() == 1 && ch == prompt_) {
      lines_.push_back(std::move(partial_));
      partial_.clear();
    }
  }
}

std::optional<std::string> LineSplitter::next() {
  if (lines_.empty()) return std::nullopt;
  std::string line = std::move(lines_.front());
  lines_.pop_front();
  return line;
}

void LineSplitter::clear() {
  partial_.clear();
  lines_.clear();
  after_cr_ = false;
}

void SerialPort::flush() {
  tcflush(fd_, TCIOFLUSH);
  lines_.clear();
}

}  // namespace s2r
