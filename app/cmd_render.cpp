// Subcommands that draw: preview (now), render/eval/view/raytrace/envmap (later).
#include "app/commands.h"
#include "render/session_preview.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {
void add_preview(CLI::App& app) {
  auto* sub = app.add_subcommand("preview", "Offscreen image of a session's depth as coloured points, from one view's camera");
  auto path = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  auto report = std::make_shared<std::string>();
  auto o = std::make_shared<PreviewOptions>();
  sub->add_option("session", *path, "session folder")->required();
  sub->add_option("--out", *out, "PNG to write (also writes *_compare.png: photo | preview)")->required();
  sub->add_option("--view", o->view, "frame whose camera draws the image (0-based)")->capture_default_str();
  sub->add_option("--stride", o->stride, "use every n-th depth pixel")->capture_default_str();
  sub->add_option("--point-size", o->point_size, "splat size in pixels (0 = auto)")->capture_default_str();
  sub->add_flag("--single-view", o->single_view, "only the chosen view's own depth");
  sub->add_option("--report", *report, "report path (default: beside --out)");
  sub->callback([=] {
    set_runner([=] {
      auto r = preview_to_file(*path, *o, *out);
      if (!r) return error(r.error().message);
      return finish(*r, report->empty() ? fs::path(*out).parent_path() / "report.json" : fs::path(*report));
    });
  });
}
}  // namespace

void add_render_commands(CLI::App& app) {
  add_preview(app);
  add_not_yet(app, "render", "Offscreen image of a model");
  add_not_yet(app, "eval", "PSNR/SSIM against held-out photos");
  add_not_yet(app, "view", "Interactive viewer");
  add_not_yet(app, "raytrace", "CPU ray tracer with visual-field LOD");
  add_not_yet(app, "envmap", "Multi-scale environment map");
}
}  // namespace s2r::cli
