// A V4L2 capture driver (webcams, UVC depth cameras) over the V4l2Io boundary.
//
// open:  QUERYCAP (capture + streaming required), ENUM_FMT, S_FMT (YUYV,
//        MJPEG, GREY or Z16), fixed exposure / gain / white balance controls
//        (a turntable capture must not drift; unsupported controls are warnings)
// start: REQBUFS (mmap, >= 2 buffers), QUERYBUF + mmap, QBUF, STREAMON
// grab:  poll with a timeout, DQBUF with EAGAIN/EINTR retry, decode, QBUF
// stop:  STREAMOFF, munmap, REQBUFS 0 — on every exit path (the destructor too)
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "capture/camera.h"
#include "capture/v4l2_io.h"

namespace s2r {

struct V4l2Config {
  int width = 640, height = 480;
  uint32_t fourcc = 0;  // 0: the first of YUYV, MJPG, Z16, GREY the device offers
  int buffers = 4;
  int timeout_ms = 2000;
  int max_eagain = 200;  // consecutive EAGAINs before giving up
  std::optional<int> exposure_100us;  // V4L2_CID_EXPOSURE_ABSOLUTE (manual exposure)
  std::optional<int> gain;
  std::optional<int> white_balance_k;
};

class V4l2Camera : public Camera {
 public:
  static Result<std::unique_ptr<V4l2Camera>> open(std::unique_ptr<V4l2Io> io, const std::string& path,
                                                  const V4l2Config& config = {});
  ~V4l2Camera() override;
  Status start() override;
  Result<CapturedFrame> grab() override;
  void stop() override;
  std::string describe() const override;
  int width() const override { return width_; }
  int height() const override { return height_; }
  uint32_t format() const { return fourcc_; }
  const std::vector<uint32_t>& formats() const { return formats_; }
  const std::vector<std::string>& warnings() const override { return warnings_; }
  const std::string& card() const { return card_; }

 private:
  V4l2Camera(std::unique_ptr<V4l2Io> io, std::string path, V4l2Config c)
      : io_(std::move(io)), path_(std::move(path)), cfg_(c) {}
  Status fail_errno(const std::string& what, int err) const;
  Status set_control(uint32_t id, int value, const char* name);
  std::unique_ptr<V4l2Io> io_;
  std::string path_, card_;
  V4l2Config cfg_;
  std::vector<uint32_t> formats_;
  std::vector<std::string> warnings_;
  uint32_t fourcc_ = 0;
  int width_ = 0, height_ = 0, stride_ = 0;
  struct Buffer { void* addr; size_t length; };
  std::vector<Buffer> buffers_;
  bool streaming_ = false;
  int64_t last_sequence_ = -1;
};

// Lists /dev/video* nodes with their driver, card and formats (for `s2r devices`).
std::vector<std::string> list_v4l2_devices();

}  // namespace s2r
