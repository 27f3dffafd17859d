// OpenGL contexts. Two front ends, one drawing code:
//   - headless: EGL without any window system (Mesa's surfaceless platform,
//     or an EGL device on a GPU machine); for tests, benchmarks, s2r render;
//   - window: GLFW (X11, e.g. under Xvfb) for the viewer.
// Drawing always goes into a Framebuffer (render/framebuffer.h) of the
// requested size; a window then blits it to the screen. So both front ends
// produce the same pixels.
#pragma once

#include <memory>
#include <string>

#include "core/result.h"

struct GLFWwindow;

namespace s2r {

class GlContext {
 public:
  virtual ~GlContext() = default;
  virtual void make_current() = 0;
  // "llvmpipe (LLVM 15.0.6, 256 bits) / 4.5 (Core Profile) Mesa 22.3.6"
  std::string describe() const;
};

Result<std::unique_ptr<GlContext>> create_headless_context();

class GlWindow : public GlContext {
 public:
  static Result<std::unique_ptr<GlWindow>> create(int width, int height, const std::string& title,
                                                  bool visible = true);
  ~GlWindow() override;
  void make_current() override;
  GLFWwindow* handle() const { return window_; }
  bool should_close() const;
  void swap_buffers();
  void poll_events();
  void framebuffer_size(int* w, int* h) const;

 private:
  explicit GlWindow(GLFWwindow* w) : window_(w) {}
  GLFWwindow* window_;
};

}  // namespace s2r
