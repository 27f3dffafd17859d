// An offscreen render target (RGBA8 colour + 24-bit depth) that both the
// headless renderer and the window draw into.
#pragma once

#include "core/image.h"
#include "core/result.h"

namespace s2r {

class Framebuffer {
 public:
  // Needs a current context. `half_float`: RGBA16F colour (blending many
  // translucent layers without 8-bit rounding at each).
  static Result<Framebuffer> create(int width, int height, bool half_float = false);
  Framebuffer(Framebuffer&&) noexcept;
  Framebuffer& operator=(Framebuffer&&) noexcept;
  Framebuffer(const Framebuffer&) = delete;
  ~Framebuffer();

  void bind() const;  // also sets the viewport
  void clear(float r, float g, float b) const;
  // Pixels top row first (image convention), RGB.
  ImageU8 read_rgb() const;
  ImageU8 read_rgba() const;  // alpha as drawn (the renderers clear it to 0)
  // Copy to the default framebuffer (a window's back buffer) of size w x h.
  void blit_to_screen(int w, int h) const;
  // Copy the colour into `other` (same size), converting its format.
  void blit_to(const Framebuffer& other) const;
  bool half_float() const { return half_float_; }
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  Framebuffer() = default;
  ImageU8 read(int channels) const;
  unsigned fbo_ = 0, color_ = 0, depth_ = 0;
  int width_ = 0, height_ = 0;
  bool half_float_ = false;
};

}  // namespace s2r
