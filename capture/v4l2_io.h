// The V4L2 device boundary: the few kernel calls a capture driver makes.
//
// V4l2Camera (v4l2_camera.h) runs over this interface, so the same driver
// code runs against:
//   - the kernel, through libv4l2 (make_kernel_v4l2_io);
//   - a recording wrapper that writes what the device answered — ioctl
//     results and structs, buffer bytes, poll results — to a file;
//   - a replay of such a file (make_replay_v4l2_io), so decode, state machine,
//     timeout and error paths are tested without hardware;
//   - a simulated UVC camera (v4l2_sim.h) fed by the synthetic rig.
// Calls return 0 / a positive count on success and -errno on failure.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "core/result.h"

namespace s2r {

class V4l2Io {
 public:
  virtual ~V4l2Io() = default;
  virtual int open(const std::string& path) = 0;
  virtual void close() = 0;
  virtual int ioctl(unsigned long request, void* arg) = 0;
  virtual void* mmap(size_t length, int64_t offset) = 0;  // nullptr on failure
  virtual void munmap(void* addr, size_t length) = 0;
  virtual int poll(int timeout_ms) = 0;  // 1 readable, 0 timeout, -errno
  virtual std::string describe() const = 0;
};

std::unique_ptr<V4l2Io> make_kernel_v4l2_io();
// Records every call of `inner` into `path` (written as it goes, fsync'ed at close).
Result<std::unique_ptr<V4l2Io>> make_recording_v4l2_io(std::unique_ptr<V4l2Io> inner,
                                                       const std::filesystem::path& path);
// Plays a recording back. A call that differs from the recorded sequence
// fails with -EPROTO and the reason in last_replay_error().
Result<std::unique_ptr<V4l2Io>> make_replay_v4l2_io(const std::filesystem::path& path);
std::string last_replay_error(const V4l2Io& io);

}  // namespace s2r
