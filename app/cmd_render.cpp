// Runs the subcommands that draw: preview, render, eval, view, raytrace,
// envmap (their flags: app/cli_render.cpp).
#include <cmath>

#include "app/run.h"
#include "render/envmap.h"
#include "render/model_eval.h"
#include "render/raytrace_job.h"
#include "render/session_preview.h"
#include "render/viewer.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {

// "a,b,c,..." -> exactly `count` finite numbers.
std::optional<std::vector<double>> numbers(const std::string& text, size_t count) {
  const auto items = comma_items(text);
  if (items.size() != count) return std::nullopt;
  std::vector<double> v(count);
  for (size_t i = 0; i < count; ++i) {
    size_t used = 0;
    try {
      v[i] = std::stod(items[i], &used);
    } catch (...) {
      return std::nullopt;
    }
    if (used != items[i].size() || !std::isfinite(v[i])) return std::nullopt;
  }
  return v;
}

// "x,y,z" -> a finite vector; named directions for --gaze.
std::optional<Eigen::Vector3d> vector3(const std::string& s) {
  if (s == "forward") return Eigen::Vector3d(0, 0, -1);
  if (s == "down") return Eigen::Vector3d(0, -1, 0);
  if (s == "right") return Eigen::Vector3d(1, 0, 0);
  if (s == "up") return Eigen::Vector3d(0, 1, 0);
  const auto v = numbers(s, 3);
  if (!v) return std::nullopt;
  return Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]);
}

// The drawing options with the two text flags parsed; an error names the flag.
// `model`: where --geometry auto looks for a fit (empty: billboards).
Result<DrawOptions> draw_options(const DrawArgs& a, const fs::path& model = {}) {
  DrawOptions d = a.d;
  d.fitted_pass = a.fitted_pass == "cpu"  ? DrawOptions::FittedPass::kCpu
                  : a.fitted_pass == "gl" ? DrawOptions::FittedPass::kGl
                                          : DrawOptions::FittedPass::kAuto;
  d.geometry = a.geometry == "mesh"      ? DrawOptions::Geometry::kMesh
               : a.geometry == "surface" ? DrawOptions::Geometry::kSurface
               : a.geometry == "fitted" || (a.geometry == "auto" && !model.empty() && model_has_fit(model))
                   ? DrawOptions::Geometry::kSplats
                   : DrawOptions::Geometry::kBillboards;
  if (a.gaze.empty()) return d;
  d.lod.field = true;
  d.lod.enabled = true;  // the field scales the octree LOD's thresholds
  if (a.gaze == "centre" || a.gaze == "center") return d;
  auto g = numbers(a.gaze, 2);
  if (!g) return fail("--gaze wants 'centre' or X,Y in pixels, got '" + a.gaze + "'");
  d.lod.gaze_px = Eigen::Vector2d((*g)[0], (*g)[1]);
  return d;
}

// Empty optional: no environment asked for; an error names the flag.
Result<std::optional<EnvironmentSetup>> environment_setup(const EnvArgs& a) {
  if (a.panorama.empty() && a.envmap.empty() && a.floor < 0 && a.spheres.empty() && a.floor_relief.empty())
    return std::optional<EnvironmentSetup>();
  EnvironmentSetup e;
  e.panorama = a.panorama;
  e.envmap = a.envmap;
  e.clamp = a.clamp;
  e.floor_roughness = a.floor;
  e.floor_roughness_texture = a.floor_map;
  e.floor_glossy = static_cast<float>(a.floor_glossy);
  e.envmap_options.size = a.envmap_size;
  if (!a.floor_map.empty() && a.floor < 0) e.floor_roughness = 0.5;
  if (!a.floor_relief.empty()) {
    auto v = numbers(a.floor_relief, 2);
    if (!v || (*v)[0] < 0 || (*v)[0] > 1000 || (*v)[1] < 0 || (*v)[1] > 1000)
      return fail("--floor-relief: expected R,D each in 0..1000, got '" + a.floor_relief + "'");
    e.floor_relief_R = (*v)[0];
    e.floor_relief_D = (*v)[1];
  }
  if (a.up == "z") e.up = Eigen::Vector3d::UnitZ();
  else if (a.up == "y") e.up = Eigen::Vector3d::UnitY();
  else if (auto v = numbers(a.up, 3); v && Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]).norm() > 0) e.up = {(*v)[0], (*v)[1], (*v)[2]};
  else return fail("--up: expected z, y or X,Y,Z (non-zero), got '" + a.up + "'");
  for (const auto& sp : a.spheres) {
    auto v = numbers(sp, 5);
    if (!v || (*v)[3] <= 0 || (*v)[4] < 0 || (*v)[4] > 1)
      return fail("--sphere: expected X,Y,Z,RADIUS,ROUGHNESS with RADIUS > 0 and ROUGHNESS in [0, 1], got '" + sp + "'");
    e.props.push_back({{(*v)[0], (*v)[1], (*v)[2]}, (*v)[3], (*v)[4]});
  }
  return std::optional<EnvironmentSetup>(std::move(e));
}

fs::path beside(const fs::path& out) { return out.parent_path() / "report.json"; }

}  // namespace

int run(const PreviewArgs& a) {
  auto r = preview_to_file(a.session, a.options, a.out);
  if (!r) return error(in_flag_terms(r.error(), {{"view", "--view"}}));
  return finish(*r, a.report.empty() ? beside(a.out) : fs::path(a.report));
}

int run(const RenderArgs& a) {
  RenderJob job = a.job;
  if (a.view >= 0) job.view = a.view;
  if (!job.view && job.view_file.empty()) return error("give --view I or --pose FILE");
  auto draw = draw_options(a.draw, job.model);
  if (!draw) return error(draw.error().message);
  job.draw = *draw;
  if (!a.background.empty()) {
    auto bg = parse_background(a.background, "--background");
    if (!bg) return error(bg.error().message);
    job.background = *bg;
  }
  auto env = environment_setup(a.env);
  if (!env) return error(env.error().message);
  job.environment = *env;
  auto r = run_render_job(job);
  if (!r) return error(in_flag_terms(r.error(), {{"scale", "--scale"}, {"session", "--session"}, {"up", "--up"}, {"panorama", "--panorama"}}));
  return finish(r->to_report(), a.report.empty() ? beside(job.out) : fs::path(a.report));
}

int run(const EvalArgs& a) {
  EvalJob job = a.job;
  auto frames = frame_list(a.holdout, "--holdout");
  if (!frames) return error(frames.error().message);
  job.frames = *frames;
  job.out = a.out.empty() ? job.model / "eval" : fs::path(a.out);
  auto draw = draw_options(a.draw);
  if (!draw) return error(draw.error().message);
  job.draw = *draw;
  if (!a.background.empty()) {
    auto bg = parse_background(a.background, "--background");
    if (!bg) return error(bg.error().message);
    job.background = *bg;
  }
  auto r = run_eval_job(job);
  if (!r) return error(in_flag_terms(r.error(), {{"frames", "--holdout"}, {"session", "--session"}}));
  return finish(r->to_report(), job.out / "report.json");
}

int run(const ViewArgs& a) {
  ViewerOptions o = a.options;
  auto draw = draw_options(a.draw, o.model);
  if (!draw) return error(draw.error().message);
  o.draw = *draw;
  auto env = environment_setup(a.env);
  if (!env) return error(env.error().message);
  o.environment = *env;
  auto r = run_viewer(o);
  if (!r) return error(in_flag_terms(r.error(), {{"up", "--up"}, {"panorama", "--panorama"}}));
  std::fprintf(stderr, "%s\n", r->brief().c_str());
  return 0;
}

int run(const RaytraceArgs& a) {
  RaytraceJob job = a.job;
  job.out = a.out;
  job.field_lod = !a.full;
  job.compare_full = !a.no_compare;
  if (!a.eye.empty()) {
    job.eye = vector3(a.eye);
    if (!job.eye || a.eye == "forward" || a.eye == "down" || a.eye == "right" || a.eye == "up")
      return error("--eye: expected x,y,z in metres, got '" + a.eye + "'");
  }
  if (!a.gaze.empty()) {
    job.gaze = vector3(a.gaze);
    if (!job.gaze) return error("--gaze: expected x,y,z or forward|down|right|up, got '" + a.gaze + "'");
  }
  static const FlagNames flags = {{"out", "--out"},       {"size", "--size"},     {"reflect_max", "--reflect-max"},
                                  {"n_min", "--n-min"},   {"levels", "--levels"}, {"eye", "--eye"},
                                  {"gaze", "--gaze"},     {"model", "--model"},   {"layout", "--layout"},
                                  {"scene", "--scene"}};
  auto r = run_raytrace_job(job);
  if (!r) return error(in_flag_terms(r.error(), flags));
  return finish(r->to_report(), fs::path(a.out) / "report.json");
}

int run(const EnvmapArgs& a) {
  auto r = run_envmap_job(a.job);
  if (!r) return error(r.error().message);
  return finish(*r, a.report.empty() ? a.job.out.parent_path() / "report.json" : fs::path(a.report));
}

}  // namespace s2r::cli
