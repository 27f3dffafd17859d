#include "capture/v4l2_sim.h"

#include <linux/videodev2.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <deque>

#include "capture/pixel_formats.h"

namespace s2r {

namespace {

class SimIo : public V4l2Io {
 public:
  explicit SimIo(V4l2SimConfig c) : cfg_(std::move(c)) {}
  int open(const std::string& path) override {
    path_ = path;
    return 0;
  }
  void close() override {}
  std::string describe() const override { return "sim:" + path_; }

  int ioctl(unsigned long request, void* arg) override {
    if (vanished_) return -ENODEV;
    switch (request) {
      case VIDIOC_QUERYCAP: {
        auto* c = static_cast<v4l2_capability*>(arg);
        std::memset(c, 0, sizeof *c);
        std::snprintf(reinterpret_cast<char*>(c->driver), sizeof c->driver, "uvcvideo");
        std::snprintf(reinterpret_cast<char*>(c->card), sizeof c->card, "%s", cfg_.card.c_str());
        c->capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING | V4L2_CAP_DEVICE_CAPS;
        c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        return 0;
      }
      case VIDIOC_ENUM_FMT: {
        auto* d = static_cast<v4l2_fmtdesc*>(arg);
        if (d->index >= cfg_.formats.size()) return -EINVAL;
        d->pixelformat = cfg_.formats[d->index];
        return 0;
      }
      case VIDIOC_S_FMT: {
        auto* f = static_cast<v4l2_format*>(arg);
        if (std::find(cfg_.formats.begin(), cfg_.formats.end(), f->fmt.pix.pixelformat) == cfg_.formats.end())
          f->fmt.pix.pixelformat = cfg_.formats.at(0);
        fourcc_ = f->fmt.pix.pixelformat;
        f->fmt.pix.width = static_cast<uint32_t>(cfg_.width);  // one size, like many UVC modes
        f->fmt.pix.height = static_cast<uint32_t>(cfg_.height);
        const uint32_t bpp = fourcc_ == kFourccGREY ? 1 : 2;
        f->fmt.pix.bytesperline = fourcc_ == kFourccMJPG ? 0 : bpp * f->fmt.pix.width;
        f->fmt.pix.sizeimage = 2 * f->fmt.pix.width * f->fmt.pix.height + 4096;
        frame_bytes_ = f->fmt.pix.sizeimage;
        return 0;
      }
      case VIDIOC_S_CTRL: return 0;
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        buffers_.assign(r->count, std::vector<char>(frame_bytes_));
        queued_.clear();
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (b->index >= buffers_.size()) return -EINVAL;
        b->length = static_cast<uint32_t>(frame_bytes_);
        b->m.offset = b->index * 0x100000u;
        return 0;
      }
      case VIDIOC_QBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (b->index >= buffers_.size()) return -EINVAL;
        queued_.push_back(b->index);
        return 0;
      }
      case VIDIOC_STREAMON: streaming_ = true; return 0;
      case VIDIOC_STREAMOFF: streaming_ = false; queued_.clear(); return 0;
      case VIDIOC_DQBUF: return dqbuf(static_cast<v4l2_buffer*>(arg));
      default: return -ENOTTY;
    }
  }

  void* mmap(size_t length, int64_t offset) override {
    const size_t index = static_cast<size_t>(offset) / 0x100000u;
    if (index >= buffers_.size() || length > buffers_[index].size()) return nullptr;
    return buffers_[index].data();
  }
  void munmap(void*, size_t) override {}

  int poll(int) override {
    if (vanished_) return -ENODEV;
    if (polls_++ == cfg_.faults.timeout_at) return 0;
    return streaming_ && !queued_.empty() ? 1 : 0;
  }

 private:
  int dqbuf(v4l2_buffer* b) {
    const auto& F = cfg_.faults;
    if (delivered_ == F.vanish_at) {
      vanished_ = true;
      return -ENODEV;
    }
    if (delivered_ == F.eio_at && !eio_done_) {
      eio_done_ = true;
      return -EIO;
    }
    if (delivered_ == F.eagain_storm_at && eagains_ < F.eagain_count) {
      ++eagains_;
      return -EAGAIN;
    }
    if (!streaming_ || queued_.empty()) return -EAGAIN;
    const uint32_t index = queued_.front();
    queued_.pop_front();
    if (delivered_ == F.drop_frame_at) ++sequence_;  // the device lost one
    SimFrame f = cfg_.source(sequence_);
    if (F.clock_jump_at >= 0 && delivered_ >= F.clock_jump_at) f.timestamp_ns += F.clock_jump_ns;
    std::string bytes;
    if (fourcc_ == kFourccYUYV) bytes = rgb_to_yuyv(f.rgb);
    else if (fourcc_ == kFourccMJPG) bytes = rgb_to_mjpeg(f.rgb);
    else if (fourcc_ == kFourccGREY) bytes = rgb_to_grey(f.rgb);
    else bytes = depth_to_z16(f.depth);
    auto& buf = buffers_[index];
    const size_t n = std::min(bytes.size(), buf.size());
    std::memcpy(buf.data(), bytes.data(), n);
    std::memset(b, 0, sizeof *b);
    b->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b->memory = V4L2_MEMORY_MMAP;
    b->index = index;
    b->bytesused = static_cast<uint32_t>(n);
    b->sequence = sequence_++;
    b->timestamp.tv_sec = f.timestamp_ns / 1'000'000'000;
    b->timestamp.tv_usec = (f.timestamp_ns % 1'000'000'000) / 1000;
    b->length = static_cast<uint32_t>(buf.size());
    b->m.offset = index * 0x100000u;
    if (delivered_ == F.corrupt_at) b->flags |= V4L2_BUF_FLAG_ERROR;
    ++delivered_;
    return 0;
  }

  V4l2SimConfig cfg_;
  std::string path_;
  uint32_t fourcc_ = 0;
  size_t frame_bytes_ = 0;
  std::vector<std::vector<char>> buffers_;
  std::deque<uint32_t> queued_;
  bool streaming_ = false, vanished_ = false, eio_done_ = false;
  int delivered_ = 0, eagains_ = 0, polls_ = 0;
  uint32_t sequence_ = 0;
};

}  // namespace

std::unique_ptr<V4l2Io> make_sim_v4l2_io(V4l2SimConfig config) { return std::make_unique<SimIo>(std::move(config)); }

}  // namespace s2r
