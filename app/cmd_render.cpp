#include "app/commands.h"

namespace s2r::cli {
void add_render_commands(CLI::App& app) {
  add_not_yet(app, "render", "Offscreen image of a model", "renderer issue");
  add_not_yet(app, "eval", "PSNR/SSIM against held-out photos", "renderer issue");
  add_not_yet(app, "view", "Interactive viewer", "renderer issue");
  add_not_yet(app, "raytrace", "CPU ray tracer with visual-field LOD", "ray tracer issue");
  add_not_yet(app, "envmap", "Multi-scale environment map", "environment map issue");
}
}  // namespace s2r::cli
