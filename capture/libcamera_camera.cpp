// The only translation unit that includes libcamera.
#include "capture/libcamera_camera.h"
#include "capture/pixel_formats.h"

#include <libcamera/libcamera.h>
#include <sys/mman.h>

#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>

#include <spdlog/spdlog.h>

namespace s2r {
namespace lc = libcamera;

struct LibcameraCamera::State {
  std::unique_ptr<lc::CameraManager> manager;
  std::shared_ptr<lc::Camera> camera;
  std::unique_ptr<lc::CameraConfiguration> config;
  std::unique_ptr<lc::FrameBufferAllocator> allocator;
  lc::Stream* stream = nullptr;
  std::vector<std::unique_ptr<lc::Request>> requests;
  std::map<const lc::FrameBuffer*, std::pair<void*, size_t>> maps;
  std::mutex mu;
  std::condition_variable cv;
  std::deque<lc::Request*> completed;
  bool acquired = false, started = false;
  int width = 0, height = 0, stride = 0;
  std::vector<std::string> warnings;

  // Runs in libcamera's thread: queue the request, never block.
  void on_complete(lc::Request* r) {
    if (r->status() == lc::Request::RequestCancelled) return;
    {
      std::lock_guard lock(mu);
      completed.push_back(r);
    }
    cv.notify_one();
  }
};

LibcameraCamera::LibcameraCamera(std::unique_ptr<State> s) : s_(std::move(s)) {}

std::vector<std::string> list_libcamera_cameras() {
  std::vector<std::string> out;
  lc::CameraManager cm;
  if (cm.start() != 0) return out;
  for (const auto& c : cm.cameras()) out.push_back(c->id());
  cm.stop();
  return out;
}

Result<std::unique_ptr<LibcameraCamera>> LibcameraCamera::open(const std::string& id, int width, int height) {
  auto s = std::make_unique<State>();
  s->manager = std::make_unique<lc::CameraManager>();
  if (int r = s->manager->start(); r != 0) return fail("libcamera: camera manager did not start (" + std::to_string(r) + ")");
  auto cams = s->manager->cameras();
  if (cams.empty()) {
    s->manager->stop();
    return fail(ErrorCode::not_found, "libcamera: no camera found (is the camera connected and its pipeline supported?)");
  }
  s->camera = id.empty() ? cams.front() : s->manager->get(id);
  if (!s->camera) {
    s->manager->stop();
    return fail(ErrorCode::not_found, "libcamera: no camera with id '" + id + "' (see `s2r devices`)");
  }
  if (s->camera->acquire() != 0) return fail("libcamera: camera '" + s->camera->id() + "' is in use by another process");
  s->acquired = true;
  s->config = s->camera->generateConfiguration({lc::StreamRole::Viewfinder});
  if (!s->config || s->config->empty()) return fail("libcamera: no configuration for a viewfinder stream");
  lc::StreamConfiguration& sc = s->config->at(0);
  sc.pixelFormat = lc::formats::RGB888;
  sc.size = lc::Size(static_cast<unsigned>(width), static_cast<unsigned>(height));
  sc.bufferCount = 4;
  const auto validity = s->config->validate();
  if (validity == lc::CameraConfiguration::Invalid)
    return fail("libcamera: configuration " + sc.toString() + " is invalid for this camera");
  // libcamera may adjust the size to what the pipeline can make (vimc: 640x480
  // becomes 636x480); the frames then have its size, and the user is told.
  if (validity == lc::CameraConfiguration::Adjusted &&
      (int(sc.size.width) != width || int(sc.size.height) != height)) {
    s->warnings.push_back("libcamera camera '" + s->camera->id() + "': asked for " + std::to_string(width) + "x" +
                          std::to_string(height) + ", granted " + std::to_string(sc.size.width) + "x" +
                          std::to_string(sc.size.height) + " (the nearest its pipeline makes)");
    spdlog::warn("{}", s->warnings.back());
  }
  if (sc.pixelFormat != lc::formats::RGB888)
    return fail(ErrorCode::unsupported, "libcamera: camera cannot deliver RGB888 (offers " + sc.pixelFormat.toString() + ")");
  if (s->camera->configure(s->config.get()) != 0) return fail("libcamera: configure failed for " + sc.toString());
  s->width = static_cast<int>(sc.size.width);
  s->height = static_cast<int>(sc.size.height);
  s->stride = static_cast<int>(sc.stride);
  s->stream = sc.stream();
  s->allocator = std::make_unique<lc::FrameBufferAllocator>(s->camera);
  if (s->allocator->allocate(s->stream) < 0) return fail("libcamera: cannot allocate frame buffers");
  for (const auto& buffer : s->allocator->buffers(s->stream)) {
    auto req = s->camera->createRequest();
    if (!req) return fail("libcamera: cannot create a request");
    if (req->addBuffer(s->stream, buffer.get()) != 0) return fail("libcamera: cannot attach a buffer to a request");
    const auto& plane = buffer->planes()[0];
    void* p = ::mmap(nullptr, plane.offset + plane.length, PROT_READ, MAP_SHARED, plane.fd.get(), 0);
    if (p == MAP_FAILED) return fail("libcamera: cannot map a frame buffer");
    s->maps[buffer.get()] = {p, plane.offset + plane.length};
    s->requests.push_back(std::move(req));
  }
  State* raw = s.get();
  s->camera->requestCompleted.connect(raw, &State::on_complete);
  return std::unique_ptr<LibcameraCamera>(new LibcameraCamera(std::move(s)));
}

LibcameraCamera::~LibcameraCamera() {
  stop();
  if (!s_) return;
  if (s_->camera) s_->camera->requestCompleted.disconnect(s_.get());
  for (auto& [fb, m] : s_->maps) ::munmap(m.first, m.second);
  s_->requests.clear();
  if (s_->allocator && s_->stream) s_->allocator->free(s_->stream);
  s_->allocator.reset();
  if (s_->acquired) s_->camera->release();
  s_->camera.reset();
  if (s_->manager) s_->manager->stop();
}

Status LibcameraCamera::start() {
  if (s_->started) return {};
  if (s_->camera->start() != 0) return fail("libcamera: camera did not start");
  s_->started = true;
  for (auto& r : s_->requests)
    if (s_->camera->queueRequest(r.get()) != 0) return fail("libcamera: cannot queue a request");
  return {};
}

void LibcameraCamera::stop() {
  if (!s_ || !s_->started) return;
  s_->camera->stop();
  s_->started = false;
  std::lock_guard lock(s_->mu);
  s_->completed.clear();
}

Result<CapturedFrame> LibcameraCamera::grab() {
  lc::Request* r = nullptr;
  {
    std::unique_lock lock(s_->mu);
    if (!s_->cv.wait_for(lock, std::chrono::seconds(3), [&] { return !s_->completed.empty(); }))
      return fail(ErrorCode::timeout, "libcamera: timed out after 3 s waiting for a frame");
    r = s_->completed.front();
    s_->completed.pop_front();
  }
  if (r->status() != lc::Request::RequestComplete) return fail("libcamera: request failed");
  const lc::FrameBuffer* fb = r->buffers().begin()->second;
  const auto& md = fb->metadata();
  CapturedFrame f;
  f.timestamp_ns = static_cast<int64_t>(md.timestamp);
  f.sequence = md.sequence;
  f.fourcc = kFourccBGR3;
  f.rgb = ImageU8(s_->width, s_->height, 3);
  const auto& map = s_->maps.at(fb);
  const auto* base = static_cast<const uint8_t*>(map.first) + fb->planes()[0].offset;
  for (int y = 0; y < s_->height; ++y)
    for (int x = 0; x < s_->width; ++x)
      for (int c = 0; c < 3; ++c)  // DRM RGB888 is B, G, R in memory
        f.rgb.at(x, y, c) = base[static_cast<size_t>(y) * s_->stride + 3 * x + (2 - c)];
  r->reuse(lc::Request::ReuseBuffers);
  if (s_->camera->queueRequest(r) != 0) return fail("libcamera: cannot requeue a request");
  return f;
}

std::string LibcameraCamera::describe() const { return "libcamera:" + (s_->camera ? s_->camera->id() : std::string("?")); }
int LibcameraCamera::width() const { return s_->width; }
const std::vector<std::string>& LibcameraCamera::warnings() const { return s_->warnings; }

int LibcameraCamera::height() const { return s_->height; }

}  // namespace s2r
