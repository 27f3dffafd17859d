#include "render/viewer.h"

#include <epoxy/gl.h>
// GLFW after epoxy: epoxy must come before any GL header.
#include <GLFW/glfw3.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "core/image_io.h"
#include "render/gl_context.h"
#include "render/model_eval.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

struct Orbit {
  Eigen::Vector3d target, up, e1, e2;
  double yaw = 0, pitch = 0, distance = 1, fov_deg = 40;
  double min_distance = 1e-3;

  Eigen::Vector3d eye() const {
    return target + distance * (std::cos(pitch) * (std::cos(yaw) * e1 + std::sin(yaw) * e2) + std::sin(pitch) * up);
  }
  // OpenCV camera frame: x right, y down, z forward (towards the target).
  ViewCamera view(int width, int height) const {
    ViewCamera v;
    const double f = 0.5 * height / std::tan(0.5 * fov_deg * std::numbers::pi / 180);
    v.K.width = width, v.K.height = height;
    v.K.fx = v.K.fy = f;
    v.K.cx = 0.5 * (width - 1), v.K.cy = 0.5 * (height - 1);
    const Eigen::Vector3d e = eye();
    const Eigen::Vector3d z = (target - e).normalized();
    Eigen::Vector3d x = z.cross(up);
    if (x.squaredNorm() < 1e-12) x = z.cross(e1);
    x.normalize();
    const Eigen::Vector3d y = z.cross(x);
    Eigen::Matrix3d R;
    R << x, y, z;
    v.world_from_camera.linear() = R;
    v.world_from_camera.translation() = e;
    return v;
  }
  void look_from(const Eigen::Vector3d& position) {
    const Eigen::Vector3d d = position - target;
    distance = std::max(d.norm(), min_distance);
    pitch = std::asin(std::clamp(d.dot(up) / distance, -1.0, 1.0));
    yaw = std::atan2(d.dot(e2), d.dot(e1));
  }
};

Orbit make_orbit(const Model& m) {
  Orbit o;
  o.target = m.bounds.isEmpty() ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : Eigen::Vector3d(m.bounds.center());
  const double radius = m.bounds.isEmpty() ? 1.0 : std::max(0.5 * m.bounds.diagonal().norm(), 1e-3);
  o.up = Eigen::Vector3d::UnitY();
  Eigen::Vector3d side = Eigen::Vector3d::UnitZ();
  if (!m.cameras.empty()) {
    o.up = -m.cameras[0].world_from_camera.linear().col(1);
    side = m.cameras[0].world_from_camera.translation() - o.target;
  }
  side -= side.dot(o.up) * o.up;
  if (side.squaredNorm() < 1e-12) side = o.up.unitOrthogonal();
  o.e1 = side.normalized();
  o.e2 = o.up.cross(o.e1);
  o.min_distance = 1e-3 * radius;
  o.distance = 2.5 * radius;
  if (!m.cameras.empty()) o.look_from(m.cameras[0].world_from_camera.translation());
  return o;
}

struct ViewerState {
  Orbit orbit;
  DrawOptions draw;
  bool dragging = false, panning = false;
  double last_x = 0, last_y = 0;
  int camera_jump = -1;
  int saved = 0, shots = 0;
  bool screenshot_now = false, save_view_now = false;
  const Model* model = nullptr;
  const ModelRenderer* renderer = nullptr;
};

const char* kHelp =
    "s2r view: left drag orbit | right drag or shift+left pan | wheel zoom\n"
    "  C depth clipping   1-4 cameras blended   M fitted / billboards / patch mesh / surface   B colour by camera\n"
    "  W wireframe (mesh)   L culling   N / shift+N next / previous input camera   R reset\n"
    "  O octree LOD   [ / ] halve / double its thresholds T_s T_b T_e   G visual-field LOD around the centre\n"
    "  K leave out blended cameras below 10 % share   T patch mesh where reliability >= 0.2 / 0.5 / 0.8 / off\n"
    "  P save view (view_NNN.json)   S screenshot (screenshot_NNN.png)   H help   Q / Esc quit\n";

std::string lod_status(const DrawOptions& d, const DrawStats& st) {
  std::string t;
  if (d.lod.enabled)
    t += fmt::format(" | LOD T_s {:.2g} T_b {:.2g} T_e {:.2g}: {} coarse for {}", d.lod.shape_px, d.lod.luminance, d.lod.texel_px,
                     st.lod.node_billboards, st.lod.facets_replaced);
  if (d.selection.min_weight > 0) t += fmt::format(" | {} blends < {:.2g} left out", st.selection.cameras_pruned, d.selection.min_weight);
  if (d.mesh_reliability > 0)
    t += fmt::format(" | mesh at reliability >= {:.2g}: {} triangles for {}", d.mesh_reliability, st.triangles, st.facets_on_mesh);
  return t;
}

void on_key(GLFWwindow* w, int key, int, int action, int mods) {
  if (action != GLFW_PRESS && action != GLFW_REPEAT) return;
  auto* s = static_cast<ViewerState*>(glfwGetWindowUserPointer(w));
  switch (key) {
    case GLFW_KEY_ESCAPE:
    case GLFW_KEY_Q: glfwSetWindowShouldClose(w, GLFW_TRUE); break;
    case GLFW_KEY_C: s->draw.depth_clip = !s->draw.depth_clip; break;
    case GLFW_KEY_1:
    case GLFW_KEY_2:
    case GLFW_KEY_3:
    case GLFW_KEY_4: s->draw.selection.cameras = key - GLFW_KEY_0; break;
    case GLFW_KEY_M: {  // fitted -> billboards -> patch mesh -> fused surface -> fitted, those the model has
      using G = DrawOptions::Geometry;
      const G cycle[] = {G::kSplats, G::kBillboards, G::kMesh, G::kSurface};
      const auto can = [&](G g) {
        return g == G::kSplats ? s->renderer->has_splats()
                               : s->renderer->has_textures() && (g == G::kBillboards || s->renderer->has_mesh(g));
      };
      const int at = int(std::find(std::begin(cycle), std::end(cycle), s->draw.geometry) - std::begin(cycle));
      for (int step = 1; step <= 4; ++step)
        if (const G g = cycle[(at + step) % 4]; can(g)) {
          s->draw.geometry = g;
          break;
        }
      break;
    }
    case GLFW_KEY_B: s->draw.color_by_camera = !s->draw.color_by_camera; break;
    case GLFW_KEY_W: s->draw.wireframe = !s->draw.wireframe; break;
    case GLFW_KEY_L: s->draw.selection.frustum_cull = s->draw.selection.backface_cull = !s->draw.selection.frustum_cull; break;
    case GLFW_KEY_N:
      if (!s->model->cameras.empty()) {
        const int n = int(s->model->cameras.size());
        s->camera_jump = ((s->camera_jump + ((mods & GLFW_MOD_SHIFT) ? -1 : 1)) % n + n) % n;
        s->orbit.look_from(s->model->cameras[size_t(s->camera_jump)].world_from_camera.translation());
      }
      break;
    case GLFW_KEY_O: s->draw.lod.enabled = !s->draw.lod.enabled; break;
    case GLFW_KEY_LEFT_BRACKET:
    case GLFW_KEY_RIGHT_BRACKET: {
      const double f = key == GLFW_KEY_LEFT_BRACKET ? 0.5 : 2.0;
      s->draw.lod.shape_px *= f, s->draw.lod.luminance *= f, s->draw.lod.texel_px *= f;
      break;
    }
    case GLFW_KEY_G:
      s->draw.lod.field = !s->draw.lod.field;
      if (s->draw.lod.field) s->draw.lod.enabled = true;
      break;
    case GLFW_KEY_K: s->draw.selection.min_weight = s->draw.selection.min_weight > 0 ? 0.0 : 0.1; break;
    case GLFW_KEY_T: {  // off -> 0.2 -> 0.5 -> 0.8 -> off
      const double r = s->draw.mesh_reliability;
      s->draw.mesh_reliability = r <= 0 ? 0.2 : r < 0.35 ? 0.5 : r < 0.65 ? 0.8 : 0.0;
      break;
    }
    case GLFW_KEY_R: s->orbit = make_orbit(*s->model); break;
    case GLFW_KEY_P: s->save_view_now = true; break;
    case GLFW_KEY_S: s->screenshot_now = true; break;
    case GLFW_KEY_H: std::fputs(kHelp, stderr); break;
    default: break;
  }
}

void on_button(GLFWwindow* w, int button, int action, int mods) {
  auto* s = static_cast<ViewerState*>(glfwGetWindowUserPointer(w));
  const bool down = action == GLFW_PRESS;
  glfwGetCursorPos(w, &s->last_x, &s->last_y);
  if (button == GLFW_MOUSE_BUTTON_LEFT) {
    s->dragging = down && !(mods & GLFW_MOD_SHIFT);
    s->panning = down && (mods & GLFW_MOD_SHIFT);
  } else if (button == GLFW_MOUSE_BUTTON_RIGHT) {
    s->panning = down;
  }
}

void on_cursor(GLFWwindow* w, double x, double y) {
  auto* s = static_cast<ViewerState*>(glfwGetWindowUserPointer(w));
  const double dx = x - s->last_x, dy = y - s->last_y;
  s->last_x = x, s->last_y = y;
  Orbit& o = s->orbit;
  if (s->dragging) {
    o.yaw -= dx * 0.01;
    o.pitch = std::clamp(o.pitch + dy * 0.01, -1.55, 1.55);
  } else if (s->panning) {
    int width = 0, height = 0;
    glfwGetFramebufferSize(w, &width, &height);
    const ViewCamera v = o.view(std::max(width, 1), std::max(height, 1));
    const double per_px = o.distance / v.K.fx;
    o.target += (-dx * v.world_from_camera.linear().col(0) - dy * v.world_from_camera.linear().col(1)) * per_px;
  }
}

void on_scroll(GLFWwindow* w, double, double dy) {
  auto* s = static_cast<ViewerState*>(glfwGetWindowUserPointer(w));
  s->orbit.distance = std::max(s->orbit.min_distance, s->orbit.distance * std::pow(0.9, dy));
}

// The status line at the top of the window: text drawn on the CPU into a
// texture (only when it changes) and blitted over the image. Not part of
// the frame, so screenshots and `render` stay the model only.
struct StatusLine {
  unsigned texture = 0, fbo = 0;
  int width = 0, height = 20;
  std::string text;
  bool broken = false;
  ~StatusLine() {
    if (fbo) glDeleteFramebuffers(1, &fbo);
    if (texture) glDeleteTextures(1, &texture);
  }
  void show(const std::string& t, int screen_w, int screen_h) {
    if (broken || screen_w <= 0 || screen_h <= height) return;
    if (t != text || screen_w != width) {
      ImageU8 img(screen_w, height, 3, 0);
      if (auto st = draw_text(img, 6, 14, 13, t); !st) {
        spdlog::warn("status line off: {}", st.error().message);
        broken = true;
        return;
      }
      if (!texture) glGenTextures(1, &texture), glGenFramebuffers(1, &fbo);
      glBindTexture(GL_TEXTURE_2D, texture);
      glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
      glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB8, screen_w, height, 0, GL_RGB, GL_UNSIGNED_BYTE, img.data.data());
      glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo);
      glFramebufferTexture2D(GL_READ_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, texture, 0);
      text = t, width = screen_w;
    }
    glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo);
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
    // Row 0 of the image is the top line: flip into GL's bottom-up screen.
    glBlitFramebuffer(0, 0, width, height, 0, screen_h, width, screen_h - height, GL_COLOR_BUFFER_BIT, GL_NEAREST);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
  }
};

fs::path next_free(const std::string& stem, const std::string& ext, int& counter) {
  fs::path p;
  do p = fmt::format("{}_{:03d}{}", stem, counter++, ext);
  while (fs::exists(p));
  return p;
}

}  // namespace

ViewCamera default_orbit_view(const Model& model, int width, int height, double yaw_rad) {
  Orbit o = make_orbit(model);
  o.yaw += yaw_rad;
  return o.view(width, height);
}

Result<Report> run_viewer(const ViewerOptions& opt) {
  // The octree is read when billboards first draw (a fitted model's view never does).
  auto model = load_model(opt.model, ModelLoad{.octree = false});
  if (!model) return std::unexpected(model.error());
  if (opt.width < 16 || opt.height < 16 || opt.width > 8192 || opt.height > 8192)
    return fail("window size must be between 16 and 8192 pixels");
  auto window = GlWindow::create(opt.width, opt.height, "s2r view " + opt.model.string());
  if (!window) return std::unexpected(window.error());
  GlWindow& win = **window;
  auto renderer = ModelRenderer::create(std::move(*model), opt.model);
  if (!renderer) return std::unexpected(renderer.error());
  ViewerState state;
  state.model = &(*renderer)->model();
  state.renderer = renderer->get();
  state.orbit = make_orbit(*state.model);
  state.draw = opt.draw;
  if (const auto& bg = state.model->background) std::copy(bg->begin(), bg->end(), state.draw.background);
  Report rep;
  rep.stage = "view";
  PreparedEnvironment env;
  if (opt.environment) {
    auto e = prepare_environment(*opt.environment, state.model->bounds);
    if (!e) return std::unexpected(e.error());
    env = std::move(*e);
    state.draw.environment = env.renderer.get();
    report_environment(env, rep);
  }
  if (!opt.start_view.empty()) {
    auto v = load_view_file(opt.start_view);
    if (!v) return std::unexpected(v.error());
    state.orbit.look_from(v->eye());
  }
  glfwSetWindowUserPointer(win.handle(), &state);
  glfwSetKeyCallback(win.handle(), on_key);
  glfwSetMouseButtonCallback(win.handle(), on_button);
  glfwSetCursorPosCallback(win.handle(), on_cursor);
  glfwSetScrollCallback(win.handle(), on_scroll);
  std::fputs(kHelp, stderr);
  if ((*renderer)->photo_passes_loaded())
    spdlog::info("{} facets, {} cameras, {:.0f} MiB of camera textures; {}", state.model->facets.size(),
                 state.model->cameras.size(), double((*renderer)->texture_bytes()) / (1 << 20), win.describe());
  else
    spdlog::info("{} facets, {} cameras, {} fitted billboards (camera textures loaded when billboards or a mesh are first "
                 "drawn: M); {}", state.model->facets.size(), state.model->cameras.size(),
                 state.model->splat_count(), win.describe());

  Stopwatch total;
  std::optional<Framebuffer> fb;
  double ms_sum = 0, ms_window = 0;
  int frames = 0, window_frames = 0;
  DrawStats last;
  ViewCamera last_view;
  StatusLine status;
  std::string status_text;
  while (!win.should_close()) {
    int width = 0, height = 0;
    win.framebuffer_size(&width, &height);
    if (width <= 0 || height <= 0) {  // minimised
      glfwWaitEvents();
      continue;
    }
    if (!fb || fb->width() != width || fb->height() != height) {
      auto f = Framebuffer::create(width, height);
      if (!f) return std::unexpected(f.error());
      fb = std::move(*f);
    }
    last_view = state.orbit.view(width, height);
    auto st = (*renderer)->draw(last_view, state.draw, *fb);
    if (!st) return std::unexpected(st.error());
    last = *st;
    fb->blit_to_screen(width, height);
    ++frames, ++window_frames;
    ms_sum += st->frame_ms, ms_window += st->frame_ms;
    if (window_frames >= 10 || opt.frames > 0 || status.text.empty()) {
      const bool mesh = state.draw.geometry == DrawOptions::Geometry::kMesh || state.draw.geometry == DrawOptions::Geometry::kSurface;
      const auto& se = st->selection;
      status_text =
          state.draw.geometry == DrawOptions::Geometry::kSplats
              ? fmt::format("fitted billboards {} | {:.1f} ms", state.model->splat_count(),
                            ms_window / window_frames)
          : mesh ? fmt::format("{} {} triangles | {:.1f} ms", state.draw.geometry == DrawOptions::Geometry::kMesh ? "patch mesh" : "surface",
                             st->triangles, ms_window / window_frames)
               : fmt::format("facets {} drawn, skipped {} frustum {} back-facing {} no camera{} | {} camera{}{} | clip {}{} | {:.1f} ms",
                             se.drawn, se.outside_frustum + st->lod.facets_outside_frustum,
                             se.back_facing + st->lod.facets_back_cone, se.no_camera,
                             state.draw.lod.field ? fmt::format(" {} outside the field", st->lod.facets_outside_field) : "",
                             state.draw.selection.cameras, state.draw.selection.cameras > 1 ? "s" : "",
                             state.draw.color_by_camera ? " (coloured)" : "", state.draw.depth_clip ? "on" : "off",
                             lod_status(state.draw, *st), ms_window / window_frames);
      glfwSetWindowTitle(win.handle(), ("s2r view | " + status_text).c_str());
      ms_window = 0, window_frames = 0;
    }
    status.show(status_text, width, height);
    win.swap_buffers();
    if (state.screenshot_now) {
      state.screenshot_now = false;
      const fs::path p = next_free("screenshot", ".png", state.shots);
      if (auto w = write_image(p, fb->read_rgb()); !w) spdlog::error("{}", w.error().message);
      else spdlog::info("screenshot {}", p.string());
    }
    if (state.save_view_now) {
      state.save_view_now = false;
      const fs::path p = next_free("view", ".json", state.saved);
      if (auto w = save_view_file(p, last_view); !w) spdlog::error("{}", w.error().message);
      else spdlog::info("view saved to {} (s2r render MODEL --pose {})", p.string(), p.string());
    }
    if (opt.orbit_deg_per_frame > 0) state.orbit.yaw += opt.orbit_deg_per_frame * std::numbers::pi / 180;
    if (opt.frames > 0 && frames >= opt.frames) break;
    win.poll_events();
  }
  if (!opt.screenshot.empty() && fb)
    if (auto w = write_image(opt.screenshot, fb->read_rgb()); !w) return std::unexpected(w.error());
  rep.counts["frames"] = frames;
  rep.counts["frame_ms_mean"] = frames ? ms_sum / frames : 0;
  rep.counts["facets_drawn_last_frame"] = double(last.selection.drawn);
  rep.skipped["facets_outside_frustum_last_frame"] = double(last.selection.outside_frustum);
  rep.skipped["facets_back_facing_last_frame"] = double(last.selection.back_facing);
  rep.params["renderer"] = win.describe();
  rep.params["status_line"] = status_text;
  rep.counts["status_line_on_screen"] = status.broken || status.text.empty() ? 0 : 1;
  rep.seconds = total.seconds();
  return rep;
}

}  // namespace s2r
