// Tests only: an X server for GLFW windows. Starts Xvfb when no display is
// set; skips (ok() false, with the reason) only if Xvfb is not installed.
#pragma once

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace s2r {

class XServer {
 public:
  XServer() {
    if (const char* d = std::getenv("DISPLAY"); d && *d) {
      ok_ = true;
      return;
    }
    const char* xvfb = "/usr/bin/Xvfb";
    if (!std::filesystem::exists(xvfb)) {
      reason_ = "Xvfb is not installed (apt-get install xvfb)";
      return;
    }
    // A display number of our own; ready when its socket appears.
    for (int attempt = 0; attempt < 20 && !ok_; ++attempt) {
      const int n = 100 + (getpid() * 7 + attempt * 13) % 800;
      if (std::filesystem::exists("/tmp/.X" + std::to_string(n) + "-lock")) continue;
      const std::string display = ":" + std::to_string(n);
      pid_ = fork();
      if (pid_ == 0) {
        execl(xvfb, "Xvfb", display.c_str(), "-screen", "0", "320x240x24", "-nolisten", "tcp",
              static_cast<char*>(nullptr));
        _exit(127);
      }
      const std::string socket = "/tmp/.X11-unix/X" + std::to_string(n);
      for (int i = 0; i < 100; ++i) {  // up to 10 s
        if (std::filesystem::exists(socket)) {
          setenv("DISPLAY", display.c_str(), 1);
          ok_ = true;
          break;
        }
        if (waitpid(pid_, nullptr, WNOHANG) == pid_) break;  // died: try another number
        usleep(100000);
      }
      if (!ok_) {
        kill(pid_, SIGTERM);
        waitpid(pid_, nullptr, 0);
        pid_ = -1;
      }
    }
    if (!ok_) reason_ = "Xvfb did not start";
  }
  ~XServer() {
    if (pid_ > 0) {
      kill(pid_, SIGTERM);
      waitpid(pid_, nullptr, 0);
      unsetenv("DISPLAY");
    }
  }
  bool ok() const { return ok_; }
  const std::string& reason() const { return reason_; }

 private:
  pid_t pid_ = -1;
  bool ok_ = false;
  std::string reason_ = "no display";
};

}  // namespace s2r
