// `s2r view`: the interactive viewer. A GLFW window around the same
// ModelRenderer the offscreen commands use (render/model_renderer.h): it
// draws into a Framebuffer and blits it, so a screenshot is the offscreen
// image of the same view.
//
// Mouse: left drag orbits, right drag (or shift + left) pans, wheel zooms.
// Keys: C depth clipping, 1-4 cameras blended, M billboards / patch mesh / surface, B colour by
// camera, W wireframe (mesh), L culling, N/Shift+N jump to the next/previous
// input camera, R reset, P save the view (view_NNN.json for s2r render
// --pose), S screenshot (screenshot_NNN.png), H help, Q/Esc quit.
// A status line over the image (and the window title) shows facets drawn /
// skipped and milliseconds per frame; it is not part of screenshots.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "core/report.h"
#include "core/result.h"
#include "render/glossy_renderer.h"
#include "render/model_renderer.h"

namespace s2r {

struct ViewerOptions {
  std::filesystem::path model;
  int width = 1280, height = 720;
  int frames = 0;                     // > 0: draw this many frames, then close (tests, timing)
  std::filesystem::path screenshot;   // written after the last frame when set
  std::filesystem::path start_view;   // a view file to start at
  double orbit_deg_per_frame = 0;     // > 0: turn the orbit each frame (timing a moving view)
  DrawOptions draw;
  std::optional<EnvironmentSetup> environment;  // backdrop, glossy floor and props
};

// The orbit camera the viewer starts from: around the model's bounds centre,
// seen from the first camera's side, up = the first camera's up.
ViewCamera default_orbit_view(const Model& model, int width, int height, double yaw_rad = 0);

Result<Report> run_viewer(const ViewerOptions& options);

}  // namespace s2r
