#include "render/framebuffer.h"

#include <epoxy/gl.h>

#include <cstring>
#include <utility>

namespace s2r {

Result<Framebuffer> Framebuffer::create(int width, int height, bool half_float) {
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384)
    return fail("framebuffer size " + std::to_string(width) + "x" + std::to_string(height) + " is out of range");
  Framebuffer f;
  f.width_ = width;
  f.height_ = height;
  f.half_float_ = half_float;
  glGenFramebuffers(1, &f.fbo_);
  glGenRenderbuffers(1, &f.color_);
  glGenRenderbuffers(1, &f.depth_);
  glBindRenderbuffer(GL_RENDERBUFFER, f.color_);
  glRenderbufferStorage(GL_RENDERBUFFER, half_float ? GL_RGBA16F : GL_RGBA8, width, height);
  glBindRenderbuffer(GL_RENDERBUFFER, f.depth_);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, width, height);
  glBindFramebuffer(GL_FRAMEBUFFER, f.fbo_);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, f.color_);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, f.depth_);
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  if (status != GL_FRAMEBUFFER_COMPLETE)
    return fail("framebuffer incomplete (status 0x" + std::to_string(status) + ")");
  return f;
}

Framebuffer::Framebuffer(Framebuffer&& o) noexcept { *this = std::move(o); }
Framebuffer& Framebuffer::operator=(Framebuffer&& o) noexcept {
  std::swap(fbo_, o.fbo_);
  std::swap(color_, o.color_);
  std::swap(depth_, o.depth_);
  std::swap(width_, o.width_);
  std::swap(height_, o.height_);
  std::swap(half_float_, o.half_float_);
  return *this;
}

Framebuffer::~Framebuffer() {
  if (fbo_) glDeleteFramebuffers(1, &fbo_);
  if (color_) glDeleteRenderbuffers(1, &color_);
  if (depth_) glDeleteRenderbuffers(1, &depth_);
}

void Framebuffer::bind() const {
  glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
  glViewport(0, 0, width_, height_);
}

void Framebuffer::clear(float r, float g, float b) const {
  bind();
  glClearColor(r, g, b, 1.f);
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
}

ImageU8 Framebuffer::read_rgb() const { return read(3); }
ImageU8 Framebuffer::read_rgba() const { return read(4); }

ImageU8 Framebuffer::read(int channels) const {
  ImageU8 img(width_, height_, channels);
  std::vector<uint8_t> rows(static_cast<size_t>(width_) * height_ * channels);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo_);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, width_, height_, channels == 4 ? GL_RGBA : GL_RGB, GL_UNSIGNED_BYTE, rows.data());
  const size_t stride = static_cast<size_t>(width_) * channels;
  for (int y = 0; y < height_; ++y)  // GL's row 0 is the bottom
    std::memcpy(img.data.data() + y * stride, rows.data() + (height_ - 1 - y) * stride, stride);
  return img;
}

void Framebuffer::blit_to_screen(int w, int h) const {
  glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo_);
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
  glBlitFramebuffer(0, 0, width_, height_, 0, 0, w, h, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

void Framebuffer::blit_to(const Framebuffer& other) const {
  glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo_);
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, other.fbo_);
  glBlitFramebuffer(0, 0, width_, height_, 0, 0, other.width_, other.height_, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, other.fbo_);
}

}  // namespace s2r
