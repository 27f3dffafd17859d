#include "capture/v4l2_camera.h"

#include <linux/videodev2.h>

#include <cstdlib>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>

#include "capture/pixel_formats.h"

namespace s2r {

namespace {
v4l2_buffer mmap_buffer(uint32_t index) {
  v4l2_buffer b{};
  b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  b.memory = V4L2_MEMORY_MMAP;
  b.index = index;
  return b;
}
}  // namespace

Status V4l2Camera::fail_errno(const std::string& what, int err) const {
  ErrorCode code = code_for_errno(err);
  std::string msg = path_ + ": " + what + " failed: " + std::strerror(err);
  if (code == ErrorCode::disconnected) msg = path_ + ": camera disconnected during " + what;
  if (err == EPROTO) {
    code = ErrorCode::protocol;  // a replay that diverged from its recording
    msg += " (" + last_replay_error(*io_) + ")";
  }
  return fail(code, msg, err);
}

Status V4l2Camera::set_control(uint32_t id, int value, const char* name) {
  v4l2_control c{};
  c.id = id;
  c.value = value;
  if (int r = io_->ioctl(VIDIOC_S_CTRL, &c); r < 0) {
    warnings_.push_back(path_ + ": control " + name + " not set (" + std::strerror(-r) + ")");
    return fail(warnings_.back());
  }
  return {};
}

Result<std::unique_ptr<V4l2Camera>> V4l2Camera::open(std::unique_ptr<V4l2Io> io, const std::string& path,
                                                     const V4l2Config& cfg) {
  if (int r = io->open(path); r < 0) {
    if (r == -ENOENT)
      return fail(ErrorCode::not_found, "no V4L2 device at '" + path + "' (is the camera plugged in? see `s2r devices`)",
                  ENOENT);
    return fail(code_for_errno(-r), "cannot open '" + path + "': " + std::strerror(-r), -r);
  }
  std::unique_ptr<V4l2Camera> cam(new V4l2Camera(std::move(io), path, cfg));
  v4l2_capability cap{};
  if (int r = cam->io_->ioctl(VIDIOC_QUERYCAP, &cap); r < 0)
    return std::unexpected(cam->fail_errno("QUERYCAP", -r).error());
  const uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  // The kernel ends the name with a NUL; a damaged recording need not (fuzz).
  cam->card_.assign(reinterpret_cast<const char*>(cap.card), strnlen(reinterpret_cast<const char*>(cap.card), sizeof cap.card));
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE)) return fail(ErrorCode::unsupported, path + " (" + cam->card_ + ") is not a video capture device");
  if (!(caps & V4L2_CAP_STREAMING)) return fail(ErrorCode::unsupported, path + " (" + cam->card_ + ") does not support streaming I/O");
  for (uint32_t i = 0;; ++i) {
    v4l2_fmtdesc d{};
    d.index = i;
    d.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (cam->io_->ioctl(VIDIOC_ENUM_FMT, &d) < 0) break;
    cam->formats_.push_back(d.pixelformat);
  }
  uint32_t want = cfg.fourcc;
  if (!want)
    for (uint32_t f : {kFourccYUYV, kFourccMJPG, kFourccZ16, kFourccGREY})
      if (std::find(cam->formats_.begin(), cam->formats_.end(), f) != cam->formats_.end()) {
        want = f;
        break;
      }
  if (!want || std::find(cam->formats_.begin(), cam->formats_.end(), want) == cam->formats_.end()) {
    std::string offered;
    for (uint32_t f : cam->formats_) offered += " " + fourcc_name(f);
    return fail(ErrorCode::unsupported, path + ": none of the supported formats (YUYV, MJPG, GREY, Z16) is offered; device has:" + offered);
  }
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  fmt.fmt.pix.width = static_cast<uint32_t>(cfg.width);
  fmt.fmt.pix.height = static_cast<uint32_t>(cfg.height);
  fmt.fmt.pix.pixelformat = want;
  fmt.fmt.pix.field = V4L2_FIELD_ANY;
  if (int r = cam->io_->ioctl(VIDIOC_S_FMT, &fmt); r < 0) return std::unexpected(cam->fail_errno("S_FMT", -r).error());
  if (fmt.fmt.pix.pixelformat != want)
    return fail(ErrorCode::protocol, path + ": device switched the format to " + fourcc_name(fmt.fmt.pix.pixelformat));
  // What the device says it gives is checked like any input: a size a
  // decoder can allocate, rows at least as long as the pixels they hold.
  const uint32_t fw = fmt.fmt.pix.width, fh = fmt.fmt.pix.height, bpl = fmt.fmt.pix.bytesperline;
  const uint32_t bytes_per_pixel = want == kFourccGREY ? 1 : want == kFourccMJPG ? 0 : 2;
  if (fw < 2 || fh < 1 || fw > 16384 || fh > 16384)
    return fail(ErrorCode::protocol, path + ": device reports a " + std::to_string(fw) + "x" + std::to_string(fh) + " frame");
  if (bpl != 0 && (bpl < bytes_per_pixel * fw || bpl > 16 * 16384))
    return fail(ErrorCode::protocol, path + ": device reports " + std::to_string(bpl) + " bytes per line for " + std::to_string(fw) +
                " pixels of " + fourcc_name(want));
  cam->fourcc_ = want;
  cam->width_ = static_cast<int>(fmt.fmt.pix.width);
  cam->height_ = static_cast<int>(fmt.fmt.pix.height);
  cam->stride_ = static_cast<int>(fmt.fmt.pix.bytesperline);
  if (cam->width_ != cfg.width || cam->height_ != cfg.height)
    cam->warnings_.push_back(path + ": asked for " + std::to_string(cfg.width) + "x" + std::to_string(cfg.height) +
                             ", device gives " + std::to_string(cam->width_) + "x" + std::to_string(cam->height_));
  // Fixed settings for a turntable capture: auto exposure, gain and white balance off.
  if (cfg.exposure_100us) {
    (void)cam->set_control(V4L2_CID_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL, "exposure_auto");
    (void)cam->set_control(V4L2_CID_EXPOSURE_ABSOLUTE, *cfg.exposure_100us, "exposure_absolute");
  }
  if (cfg.gain) {
    (void)cam->set_control(V4L2_CID_AUTOGAIN, 0, "autogain");
    (void)cam->set_control(V4L2_CID_GAIN, *cfg.gain, "gain");
  }
  if (cfg.white_balance_k) {
    (void)cam->set_control(V4L2_CID_AUTO_WHITE_BALANCE, 0, "auto_white_balance");
    (void)cam->set_control(V4L2_CID_WHITE_BALANCE_TEMPERATURE, *cfg.white_balance_k, "white_balance_temperature");
  }
  return cam;
}

V4l2Camera::~V4l2Camera() {
  stop();
  io_->close();
}

Status V4l2Camera::start() {
  if (streaming_) return {};
  v4l2_requestbuffers req{};
  req.count = static_cast<uint32_t>(std::max(2, cfg_.buffers));
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (int r = io_->ioctl(VIDIOC_REQBUFS, &req); r < 0) return fail_errno("REQBUFS", -r);
  if (req.count < 2) return fail(ErrorCode::protocol, path_ + ": device granted " + std::to_string(req.count) + " buffer(s); 2 are needed");
  for (uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer b = mmap_buffer(i);
    if (int r = io_->ioctl(VIDIOC_QUERYBUF, &b); r < 0) {
      stop();
      return fail_errno("QUERYBUF", -r);
    }
    // A buffer length no frame of this size needs (a broken device or
    // recording) is refused before anything is mapped or allocated.
    const uint64_t frame_bytes = uint64_t(width_) * height_ * 4;
    if (b.length == 0 || b.length > std::max<uint64_t>(64u << 20, 4 * frame_bytes)) {
      stop();
      return fail(ErrorCode::protocol, path_ + ": device reports buffer " + std::to_string(i) + " of " + std::to_string(b.length) +
                  " bytes for " + std::to_string(width_) + "x" + std::to_string(height_) + " frames");
    }
    void* p = io_->mmap(b.length, b.m.offset);
    if (!p) {
      stop();
      return fail(ErrorCode::io, path_ + ": mmap of buffer " + std::to_string(i) + " failed");
    }
    buffers_.push_back({p, b.length});
  }
  for (uint32_t i = 0; i < static_cast<uint32_t>(buffers_.size()); ++i) {
    v4l2_buffer b = mmap_buffer(i);
    if (int r = io_->ioctl(VIDIOC_QBUF, &b); r < 0) {
      stop();
      return fail_errno("QBUF", -r);
    }
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (int r = io_->ioctl(VIDIOC_STREAMON, &type); r < 0) {
    stop();
    return fail_errno("STREAMON", -r);
  }
  streaming_ = true;
  return {};
}

void V4l2Camera::stop() {
  if (streaming_) {
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    (void)io_->ioctl(VIDIOC_STREAMOFF, &type);
    streaming_ = false;
  }
  if (!buffers_.empty()) {
    for (auto& b : buffers_) io_->munmap(b.addr, b.length);
    buffers_.clear();
    v4l2_requestbuffers req{};
    req.count = 0;
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    (void)io_->ioctl(VIDIOC_REQBUFS, &req);
  }
}

Result<CapturedFrame> V4l2Camera::grab() {
  if (!streaming_) return fail(ErrorCode::invalid, path_ + ": grab before start");
  int eagain = 0;
  for (;;) {
    const int pr = io_->poll(cfg_.timeout_ms);
    if (pr == -EINTR) continue;
    if (pr < 0) {
      // The kernel answers EPOLLERR both when the device is gone and after a
      // fatal streaming error (vb2_queue_error), where the application must
      // stop streaming; only a device still registered accepts STREAMOFF.
      int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      const int off = io_->ioctl(VIDIOC_STREAMOFF, &type);
      streaming_ = false;
      if (off == 0)
        return fail(ErrorCode::device_fault, path_ + ": the driver reported a fatal streaming error (the device is "
                                                     "still there; streaming was stopped: start it again)");
      return std::unexpected(fail_errno("poll", -pr).error());
    }
    if (pr == 0) return fail(ErrorCode::timeout, path_ + ": timed out after " + std::to_string(cfg_.timeout_ms) + " ms waiting for a frame");
    v4l2_buffer b = mmap_buffer(0);
    const int r = io_->ioctl(VIDIOC_DQBUF, &b);
    if (r == -EAGAIN || r == -EINTR) {
      if (++eagain > cfg_.max_eagain)
        return fail(ErrorCode::protocol, path_ + ": " + std::to_string(eagain) + " EAGAINs in a row: the device signals frames it never delivers");
      continue;
    }
    if (r < 0) return std::unexpected(fail_errno("DQBUF", -r).error());
    if (b.index >= buffers_.size()) return fail(ErrorCode::protocol, path_ + ": device returned buffer " + std::to_string(b.index));
    CapturedFrame f;
    f.fourcc = fourcc_;
    f.sequence = b.sequence;
    // A timestamp beyond +-290 years (a broken device or recording) would
    // overflow nanoseconds: it is kept as 0, "unknown".
    if (std::abs(int64_t(b.timestamp.tv_sec)) < int64_t(9'000'000'000) && b.timestamp.tv_usec >= 0 && b.timestamp.tv_usec < 1'000'000)
      f.timestamp_ns = int64_t(b.timestamp.tv_sec) * 1'000'000'000 + int64_t(b.timestamp.tv_usec) * 1000;
    if (last_sequence_ >= 0 && b.sequence > last_sequence_ + 1)
      f.dropped_before = static_cast<uint32_t>(b.sequence - last_sequence_ - 1);
    last_sequence_ = b.sequence;
    const bool corrupt = b.flags & V4L2_BUF_FLAG_ERROR;
    std::string_view data(static_cast<const char*>(buffers_[b.index].addr), std::min<size_t>(b.bytesused, buffers_[b.index].length));
    Status decoded;
    if (!corrupt) {
      if (fourcc_ == kFourccYUYV) {
        auto img = yuyv_to_rgb(data, width_, height_, stride_);
        if (img) f.rgb = std::move(*img); else decoded = std::unexpected(img.error());
      } else if (fourcc_ == kFourccMJPG) {
        auto img = mjpeg_to_rgb(data, width_, height_);
        if (img) f.rgb = std::move(*img); else decoded = std::unexpected(img.error());
      } else if (fourcc_ == kFourccGREY) {
        auto img = grey_to_rgb(data, width_, height_, stride_);
        if (img) f.rgb = std::move(*img); else decoded = std::unexpected(img.error());
      } else {
        auto img = z16_to_depth(data, width_, height_, stride_);
        if (img) f.depth = std::move(*img); else decoded = std::unexpected(img.error());
      }
    }
    if (int q = io_->ioctl(VIDIOC_QBUF, &b); q < 0) return std::unexpected(fail_errno("QBUF", -q).error());
    if (corrupt || !decoded) {
      // A damaged frame is skipped, never passed on; the next one is taken.
      warnings_.push_back(path_ + ": frame " + std::to_string(b.sequence) + " skipped: " +
                          (corrupt ? std::string("device flagged it as corrupt") : decoded.error().message));
      continue;
    }
    return f;
  }
}

std::string V4l2Camera::describe() const {
  return io_->describe() + " " + card_ + " " + fourcc_name(fourcc_) + " " + std::to_string(width_) + "x" +
         std::to_string(height_);
}

std::vector<std::string> list_v4l2_devices() {
  std::vector<std::string> out;
  std::error_code ec;
  std::vector<std::filesystem::path> nodes;
  for (const auto& e : std::filesystem::directory_iterator("/dev", ec))
    if (e.path().filename().string().rfind("video", 0) == 0) nodes.push_back(e.path());
  std::sort(nodes.begin(), nodes.end());
  for (const auto& n : nodes) {
    auto cam = V4l2Camera::open(make_kernel_v4l2_io(), n.string(), {});
    if (!cam) {
      out.push_back(n.string() + ": " + cam.error().message);
      continue;
    }
    std::string formats;
    for (uint32_t f : (*cam)->formats()) formats += (formats.empty() ? "" : ",") + fourcc_name(f);
    out.push_back(n.string() + ": " + (*cam)->card() + " [" + formats + "]" +
                  (std::find((*cam)->formats().begin(), (*cam)->formats().end(), kFourccZ16) != (*cam)->formats().end()
                       ? " depth"
                       : ""));
  }
  return out;
}

}  // namespace s2r
