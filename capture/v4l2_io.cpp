// Kernel, recording and replay implementations of the V4L2 device boundary.
#include <fcntl.h>
#include <libv4l2.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <vector>

#include "capture/v4l2_io.h"
#include "core/atomic_file.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

// --- kernel (libv4l2, format conversion disabled: raw formats only) ------------
class KernelIo : public V4l2Io {
 public:
  ~KernelIo() override { close(); }
  int open(const std::string& path) override {
    path_ = path;
    int fd = ::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return -errno;
    fd_ = v4l2_fd_open(fd, V4L2_DISABLE_CONVERSION);
    if (fd_ < 0) {
      int err = errno;
      ::close(fd);
      return -err;
    }
    return 0;
  }
  void close() override {
    if (fd_ >= 0) v4l2_close(fd_);
    fd_ = -1;
  }
  int ioctl(unsigned long request, void* arg) override {
    return v4l2_ioctl(fd_, request, arg) < 0 ? -errno : 0;
  }
  void* mmap(size_t length, int64_t offset) override {
    void* p = v4l2_mmap(nullptr, length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, offset);
    return p == MAP_FAILED ? nullptr : p;
  }
  void munmap(void* addr, size_t length) override { v4l2_munmap(addr, length); }
  int poll(int timeout_ms) override {
    pollfd pfd{fd_, POLLIN, 0};
    int r = ::poll(&pfd, 1, timeout_ms);
    if (r < 0) return -errno;
    if (r > 0 && (pfd.revents & (POLLERR | POLLHUP | POLLNVAL))) return -ENODEV;
    return r > 0 ? 1 : 0;
  }
  std::string describe() const override { return "v4l2:" + path_; }

 private:
  int fd_ = -1;
  std::string path_;
};

// --- recording format ------------------------------------------------------------
// "S2RV4L2\n" then records: u8 kind, u64 request, i64 result, u32 size, bytes.
enum Kind : uint8_t { kOpen = 1, kIoctl = 2, kMmap = 3, kPoll = 4, kData = 5, kClose = 6 };
constexpr char kMagic[8] = {'S', '2', 'R', 'V', '4', 'L', '2', '\n'};

struct Record {
  Kind kind;
  uint64_t request;
  int64_t result;
  std::string bytes;
};

size_t arg_size(unsigned long request) { return _IOC_SIZE(request); }

const char* kind_name(Kind k) {
  switch (k) {
    case kOpen: return "open";
    case kIoctl: return "ioctl";
    case kMmap: return "mmap";
    case kPoll: return "poll";
    case kData: return "data";
    case kClose: return "close";
  }
  return "?";
}

class RecordingIo : public V4l2Io {
 public:
  RecordingIo(std::unique_ptr<V4l2Io> inner, fs::path path, FILE* f) : inner_(std::move(inner)), path_(std::move(path)), f_(f) {
    std::fwrite(kMagic, 1, 8, f_);
  }
  ~RecordingIo() override {
    if (f_) {
      std::fflush(f_);
      ::fsync(fileno(f_));
      std::fclose(f_);
    }
  }
  int open(const std::string& p) override {
    const int r = inner_->open(p);
    put(kOpen, 0, r, p);
    return r;
  }
  void close() override {
    inner_->close();
    put(kClose, 0, 0, {});
  }
  int ioctl(unsigned long request, void* arg) override {
    const int r = inner_->ioctl(request, arg);
    put(kIoctl, request, r, std::string(static_cast<const char*>(arg), arg_size(request)));
    if (request == VIDIOC_QUERYBUF && r == 0) {
      const auto* b = static_cast<const v4l2_buffer*>(arg);
      offsets_[b->index] = b->m.offset;
    }
    if (request == VIDIOC_DQBUF && r == 0) {
      const auto* b = static_cast<const v4l2_buffer*>(arg);
      auto it = offsets_.find(b->index);
      const char* base = it != offsets_.end() ? static_cast<const char*>(maps_[it->second]) : nullptr;
      put(kData, b->index, 0, base ? std::string(base, b->bytesused) : std::string());
    }
    return r;
  }
  void* mmap(size_t length, int64_t offset) override {
    void* p = inner_->mmap(length, offset);
    put(kMmap, static_cast<uint64_t>(offset), p ? 0 : -1, std::to_string(length));
    if (p) maps_[static_cast<uint32_t>(offset)] = p;
    return p;
  }
  void munmap(void* addr, size_t length) override { inner_->munmap(addr, length); }
  int poll(int timeout_ms) override {
    const int r = inner_->poll(timeout_ms);
    put(kPoll, static_cast<uint64_t>(timeout_ms), r, {});
    return r;
  }
  std::string describe() const override { return inner_->describe() + " (recording to " + path_.string() + ")"; }

 private:
  void put(Kind k, uint64_t request, int64_t result, const std::string& bytes) {
    const uint32_t n = static_cast<uint32_t>(bytes.size());
    const uint8_t kind = k;
    std::fwrite(&kind, 1, 1, f_);
    std::fwrite(&request, 8, 1, f_);
    std::fwrite(&result, 8, 1, f_);
    std::fwrite(&n, 4, 1, f_);
    if (n) std::fwrite(bytes.data(), 1, n, f_);
  }
  std::unique_ptr<V4l2Io> inner_;
  fs::path path_;
  FILE* f_;
  std::map<uint32_t, uint32_t> offsets_;  // buffer index -> mmap offset
  std::map<uint32_t, void*> maps_;        // mmap offset -> address
};

class ReplayIo : public V4l2Io {
 public:
  ReplayIo(std::vector<Record> records, fs::path path) : records_(std::move(records)), path_(std::move(path)) {}
  int open(const std::string&) override {
    const Record* r = next(kOpen, 0);
    return r ? static_cast<int>(r->result) : -EPROTO;
  }
  void close() override {
    if (pos_ < records_.size() && records_[pos_].kind == kClose) ++pos_;
  }
  int ioctl(unsigned long request, void* arg) override {
    const Record* r = next(kIoctl, request);
    if (!r) return -EPROTO;
    if (r->bytes.size() != arg_size(request)) return diverged("ioctl argument size differs");
    std::memcpy(arg, r->bytes.data(), r->bytes.size());
    if (request == VIDIOC_QUERYBUF && r->result == 0) {
      const auto* b = static_cast<const v4l2_buffer*>(arg);
      offsets_[b->index] = b->m.offset;
    }
    if (request == VIDIOC_DQBUF && r->result == 0) {
      const auto* b = static_cast<const v4l2_buffer*>(arg);
      const Record* d = next(kData, b->index);
      if (!d) return -EPROTO;
      auto it = offsets_.find(b->index);
      if (it == offsets_.end() || !buffers_.count(it->second)) return diverged("DQBUF of an unmapped buffer");
      auto& buf = buffers_[it->second];
      if (d->bytes.size() > buf.size()) return diverged("recorded frame larger than its buffer");
      std::memcpy(buf.data(), d->bytes.data(), d->bytes.size());
    }
    return static_cast<int>(r->result);
  }
  void* mmap(size_t length, int64_t offset) override {
    const Record* r = next(kMmap, static_cast<uint64_t>(offset));
    if (!r || r->result != 0) return nullptr;
    auto& buf = buffers_[static_cast<uint32_t>(offset)];
    buf.assign(length, 0);
    return buf.data();
  }
  void munmap(void*, size_t) override {}
  int poll(int) override {
    const Record* r = next(kPoll, ~uint64_t(0));
    return r ? static_cast<int>(r->result) : -EPROTO;
  }
  std::string describe() const override { return "replay:" + path_.string(); }
  std::string error;

 private:
  int diverged(const std::string& why) {
    error = path_.string() + ": replay diverged at record " + std::to_string(pos_) + ": " + why;
    return -EPROTO;
  }
  const Record* next(Kind k, uint64_t request) {
    if (pos_ >= records_.size()) {
      diverged(std::string("recording ended; driver asked for ") + kind_name(k));
      return nullptr;
    }
    const Record& r = records_[pos_];
    if (r.kind != k || (request != ~uint64_t(0) && k != kPoll && k != kOpen && r.request != request)) {
      char buf[160];
      std::snprintf(buf, sizeof buf, "driver asked for %s 0x%llx, recording has %s 0x%llx", kind_name(k),
                    static_cast<unsigned long long>(request), kind_name(r.kind),
                    static_cast<unsigned long long>(r.request));
      diverged(buf);
      return nullptr;
    }
    ++pos_;
    return &r;
  }
  std::vector<Record> records_;
  fs::path path_;
  size_t pos_ = 0;
  std::map<uint32_t, uint32_t> offsets_;
  std::map<uint32_t, std::vector<char>> buffers_;
};

}  // namespace

std::unique_ptr<V4l2Io> make_kernel_v4l2_io() { return std::make_unique<KernelIo>(); }

Result<std::unique_ptr<V4l2Io>> make_recording_v4l2_io(std::unique_ptr<V4l2Io> inner, const fs::path& path) {
  std::error_code ec;
  if (path.has_parent_path()) fs::create_directories(path.parent_path(), ec);
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return fail("cannot write V4L2 recording '" + path.string() + "': " + std::strerror(errno));
  return std::unique_ptr<V4l2Io>(new RecordingIo(std::move(inner), path, f));
}

Result<std::unique_ptr<V4l2Io>> make_replay_v4l2_io(const fs::path& path) {
  auto bytes = read_file(path);
  if (!bytes) return std::unexpected(bytes.error());
  const std::string& b = *bytes;
  if (b.size() < 8 || std::memcmp(b.data(), kMagic, 8) != 0)
    return fail("'" + path.string() + "': not a V4L2 recording (bad magic)");
  std::vector<Record> records;
  size_t p = 8;
  while (p < b.size()) {
    if (b.size() - p < 21) return fail("'" + path.string() + "': truncated record header at byte " + std::to_string(p));
    Record r;
    uint8_t kind;
    uint32_t n;
    std::memcpy(&kind, b.data() + p, 1);
    std::memcpy(&r.request, b.data() + p + 1, 8);
    std::memcpy(&r.result, b.data() + p + 9, 8);
    std::memcpy(&n, b.data() + p + 17, 4);
    p += 21;
    if (kind < kOpen || kind > kClose) return fail("'" + path.string() + "': unknown record kind " + std::to_string(kind));
    // A call returns a count or descriptor (>= 0) or a negated errno (the
    // kernel's are 1..4095); anything else is damage, and the driver would
    // negate it (fuzz: INT_MIN, whose negation overflows).
    if (r.result < -4095 || r.result > std::numeric_limits<int32_t>::max())
      return fail("'" + path.string() + "': record " + std::to_string(records.size()) + " returns " + std::to_string(r.result) +
                  ", neither a count nor an errno");
    if (n > b.size() - p) return fail("'" + path.string() + "': truncated record at byte " + std::to_string(p));
    r.kind = static_cast<Kind>(kind);
    r.bytes = b.substr(p, n);
    p += n;
    records.push_back(std::move(r));
  }
  return std::unique_ptr<V4l2Io>(new ReplayIo(std::move(records), path));
}

std::string last_replay_error(const V4l2Io& io) {
  if (const auto* r = dynamic_cast<const ReplayIo*>(&io)) return r->error;
  return {};
}

}  // namespace s2r
