// The device side of a simulated serial board: a pseudo-terminal whose slave
// end the real termios code opens as it would an Arduino's port.
#pragma once

#include <string>
#include <string_view>

#include "core/result.h"

namespace s2r {

// A raw pty pair (no echo, no CR/LF translation before the host opens the
// port); the master is non-blocking. `path` is the slave's name.
Status open_pty(int* master, int* slave, std::string* path);
// Writes all of `bytes` to a non-blocking fd, waiting out EAGAIN; gives up
// silently when the other side is gone (the board was "unplugged").
void write_all(int fd, std::string_view bytes);

}  // namespace s2r
