#include "capture/pty_device.h"

#include <fcntl.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>

namespace s2r {

Status open_pty(int* master, int* slave, std::string* path) {
  char name[128] = {};
  if (openpty(master, slave, name, nullptr, nullptr) != 0) return fail(ErrorCode::io, "openpty failed", errno);
  termios tio{};
  tcgetattr(*slave, &tio);
  cfmakeraw(&tio);
  tcsetattr(*slave, TCSANOW, &tio);
  fcntl(*master, F_SETFL, fcntl(*master, F_GETFL) | O_NONBLOCK);
  *path = name;
  return {};
}

void write_all(int fd, std::string_view bytes) {
  if (fd < 0) return;
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n <= 0) {
      if (errno == EAGAIN || errno == EINTR) {
        usleep(1000);
        continue;
      }
      return;
    }
    done += static_cast<size_t>(n);
  }
}

}  // namespace s2r
