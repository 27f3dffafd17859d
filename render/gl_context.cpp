#include "render/gl_context.h"

#include <epoxy/egl.h>
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <mutex>
#include <vector>

namespace s2r {

std::string GlContext::describe() const {
  auto s = [](GLenum e) {
    const auto* p = glGetString(e);
    return p ? std::string(reinterpret_cast<const char*>(p)) : std::string("?");
  };
  return s(GL_RENDERER) + " / " + s(GL_VERSION);
}

namespace {

class EglContext : public GlContext {
 public:
  EglContext(EGLDisplay d, EGLContext c) : display_(d), context_(c) {}
  ~EglContext() override {
    eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(display_, context_);
    eglTerminate(display_);
  }
  void make_current() override { eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, context_); }

 private:
  EGLDisplay display_;
  EGLContext context_;
};

std::string egl_error() {
  char buf[32];
  std::snprintf(buf, sizeof buf, "0x%04x", eglGetError());
  return buf;
}

// Surfaceless Mesa first (no X, no GPU), then the first EGL device (a GPU
// driver without a window system), then the default display.
EGLDisplay open_display(std::string* tried) {
  if (epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_MESA_platform_surfaceless")) {
    EGLDisplay d = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    if (d != EGL_NO_DISPLAY && eglInitialize(d, nullptr, nullptr)) return d;
    *tried += " surfaceless(" + egl_error() + ")";
  }
  if (epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_EXT_device_enumeration")) {
    EGLDeviceEXT devices[8];
    EGLint n = 0;
    if (eglQueryDevicesEXT(8, devices, &n) && n > 0) {
      EGLDisplay d = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[0], nullptr);
      if (d != EGL_NO_DISPLAY && eglInitialize(d, nullptr, nullptr)) return d;
      *tried += " device(" + egl_error() + ")";
    }
  }
  EGLDisplay d = eglGetDisplay(EGL_DEFAULT_DISPLAY);
  if (d != EGL_NO_DISPLAY && eglInitialize(d, nullptr, nullptr)) return d;
  *tried += " default(" + egl_error() + ")";
  return EGL_NO_DISPLAY;
}

}  // namespace

Result<std::unique_ptr<GlContext>> create_headless_context() {
  std::string tried;
  EGLDisplay display = open_display(&tried);
  if (display == EGL_NO_DISPLAY)
    return fail("no headless OpenGL: EGL display unavailable (tried" + tried +
                "); install libegl-mesa0 and libgl1-mesa-dri");
  if (!eglBindAPI(EGL_OPENGL_API)) return fail("EGL: desktop OpenGL API not available (" + egl_error() + ")");
  const EGLint config_attribs[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
                                   EGL_RED_SIZE, 8, EGL_GREEN_SIZE, 8, EGL_BLUE_SIZE, 8, EGL_NONE};
  EGLConfig config;
  EGLint n = 0;
  if (!eglChooseConfig(display, config_attribs, &config, 1, &n) || n < 1) {
    eglTerminate(display);
    return fail("EGL: no OpenGL-capable config (" + egl_error() + ")");
  }
  for (int minor : {5, 3}) {
    const EGLint ctx_attribs[] = {EGL_CONTEXT_MAJOR_VERSION, minor == 5 ? 4 : 3, EGL_CONTEXT_MINOR_VERSION, minor,
                                  EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    EGLContext ctx = eglCreateContext(display, config, EGL_NO_CONTEXT, ctx_attribs);
    if (ctx == EGL_NO_CONTEXT) continue;
    if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx)) {
      eglDestroyContext(display, ctx);
      continue;
    }
    return std::unique_ptr<GlContext>(new EglContext(display, ctx));
  }
  eglTerminate(display);
  return fail("EGL: cannot create an OpenGL 3.3+ core context without a surface (" + egl_error() + ")");
}

namespace {
std::mutex g_glfw_mutex;
int g_glfw_users = 0;
std::string g_glfw_error;
}  // namespace

Result<std::unique_ptr<GlWindow>> GlWindow::create(int width, int height, const std::string& title,
                                                   bool visible) {
  std::lock_guard lock(g_glfw_mutex);
  if (g_glfw_users == 0) {
    glfwSetErrorCallback([](int, const char* msg) { g_glfw_error = msg; });
    if (!glfwInit())
      return fail("cannot open a window: " + g_glfw_error +
                  " (no X display? set DISPLAY or run under xvfb-run)");
  }
  glfwDefaultWindowHints();
  glfwWindowHint(GLFW_VISIBLE, visible ? GLFW_TRUE : GLFW_FALSE);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  GLFWwindow* w = nullptr;
  for (auto [major, minor] : {std::pair{4, 5}, std::pair{3, 3}}) {
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, major);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, minor);
    w = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
    if (w) break;
  }
  if (!w) {
    if (g_glfw_users == 0) glfwTerminate();
    return fail("cannot create an OpenGL 3.3+ core window: " + g_glfw_error);
  }
  ++g_glfw_users;
  glfwMakeContextCurrent(w);
  glfwSwapInterval(0);
  return std::unique_ptr<GlWindow>(new GlWindow(w));
}

GlWindow::~GlWindow() {
  std::lock_guard lock(g_glfw_mutex);
  glfwDestroyWindow(window_);
  if (--g_glfw_users == 0) glfwTerminate();
}

void GlWindow::make_current() { glfwMakeContextCurrent(window_); }
bool GlWindow::should_close() const { return glfwWindowShouldClose(window_); }
void GlWindow::swap_buffers() { glfwSwapBuffers(window_); }
void GlWindow::poll_events() { glfwPollEvents(); }
void GlWindow::framebuffer_size(int* w, int* h) const { glfwGetFramebufferSize(window_, w, h); }

}  // namespace s2r
