// A camera through libcamera (Raspberry Pi cameras and other ISP pipelines):
// CameraManager, generateConfiguration + validate, FrameBufferAllocator,
// Requests; requestCompleted is handled without blocking (a queue), grab()
// waits on it with a timeout; teardown stops, frees and releases in order.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "capture/camera.h"

namespace s2r {

class LibcameraCamera : public Camera {
 public:
  // `id`: a camera id from `s2r devices`, or "" for the first camera.
  static Result<std::unique_ptr<LibcameraCamera>> open(const std::string& id, int width, int height);
  ~LibcameraCamera() override;
  Status start() override;
  Result<CapturedFrame> grab() override;
  void stop() override;
  std::string describe() const override;
  int width() const override;
  int height() const override;
  const std::vector<std::string>& warnings() const override;

  struct State;

 private:
  explicit LibcameraCamera(std::unique_ptr<State> s);
  std::unique_ptr<State> s_;
};

// "id (model)" per camera; empty when none (no libcamera pipeline matched).
std::vector<std::string> list_libcamera_cameras();

}  // namespace s2r
