// Subcommands that draw: preview, render, eval, view, raytrace, envmap.
#include <cmath>

#include "app/commands.h"
#include "render/envmap.h"
#include "render/raytrace_job.h"
#include "render/model_eval.h"
#include "render/viewer.h"
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
// The drawing options every model command shares, bound straight to
// DrawOptions (each default is the renderer's own); only the two options
// that need parsing are held as text.
struct DrawArgs {
  DrawOptions d;
  std::string geometry = "billboards";
  std::string gaze;  // "" off, "centre", or X,Y pixels
};

void add_draw_options(CLI::App* sub, DrawArgs& a) {
  DrawOptions& d = a.d;
  sub->add_option("--geometry", a.geometry, "billboards | mesh (the octree's patch mesh, textured) | surface (the fused surface mesh, textured)")
      ->check(CLI::IsMember({"billboards", "mesh", "surface"}))->capture_default_str();
  sub->add_option("--cameras", d.selection.cameras, "k: input cameras blended per facet (1-4)")->check(CLI::Range(1, 4))->capture_default_str();
  sub->add_flag_callback("--no-clip", [&d] { d.depth_clip = false; }, "billboards without depth clipping (the paper's comparison)");
  sub->add_option("--pixel-error", d.pixel_error, "clip widens where a texel stays within this many pixels (0: fixed clip)")->capture_default_str();
  sub->add_option("--refine", d.refine_steps, "texel refinement steps along the view ray (0: the texel at the billboard point)")->capture_default_str();
  sub->add_option("--clip", d.clip_scale, "depth-clipping threshold |d - D| < clip * w")->check(CLI::PositiveNumber)->capture_default_str();
  sub->add_option("--billboard-scale", d.billboard_scale, "billboard width / w (at least sqrt 3)")->capture_default_str();
  sub->add_flag("--by-camera", d.color_by_camera, "colour each facet by its chosen camera");
  sub->add_flag_callback("--no-cull", [&d] { d.selection.frustum_cull = d.selection.backface_cull = false; },
                         "draw every facet (no frustum or back-face culling)");
  sub->add_option("--min-weight", d.selection.min_weight, "leave out blended cameras whose share is below this (0: keep the best k)")
      ->check(CLI::Range(0.0, 0.5))->capture_default_str();
  sub->add_flag("--lod", d.lod.enabled, "octree level of detail: coarser billboards where the contour, luminance and texel tests allow");
  sub->add_option("--lod-shape", d.lod.shape_px, "T_s: contour shape error allowed on screen (pixels)")
      ->check(CLI::PositiveNumber)->capture_default_str();
  sub->add_option("--lod-luminance", d.lod.luminance, "T_b: luminance range (0..1) x projected node side (pixels) allowed")
      ->check(CLI::PositiveNumber)->capture_default_str();
  sub->add_option("--lod-texel", d.lod.texel_px, "T_e: texel misplacement bound of a coarse billboard on screen (pixels)")
      ->check(CLI::PositiveNumber)->capture_default_str();
  sub->add_option("--gaze", a.gaze, "visual-field LOD around a gaze point (turns --lod on): 'centre' or X,Y in pixels; "
                  "coarser in the periphery, nothing outside the field");
  sub->add_option("--mesh-reliable", d.mesh_reliability, "billboards: draw the textured patch mesh where the geometry's "
                  "reliability is at least R (0..1), billboards elsewhere; 0: billboards everywhere (eval: adds a 'hybrid' row)")
      ->check(CLI::Range(0.0, 1.0))->capture_default_str();
}

DrawOptions draw_options(const DrawArgs& a) {
  DrawOptions d = a.d;
  d.geometry = a.geometry == "mesh"      ? DrawOptions::Geometry::kMesh
               : a.geometry == "surface" ? DrawOptions::Geometry::kSurface
                                         : DrawOptions::Geometry::kBillboards;
  return d;
}

std::optional<std::vector<double>> numbers(const std::string& text, size_t count);

// --gaze: false with a message in `why` when malformed.
bool apply_gaze(const DrawArgs& a, DrawOptions& d, std::string* why) {
  if (a.gaze.empty()) return true;
  d.lod.field = true;
  d.lod.enabled = true;  // the field scales the octree LOD's thresholds
  if (a.gaze == "centre" || a.gaze == "center") return true;
  auto g = numbers(a.gaze, 2);
  if (!g) {
    *why = "--gaze wants 'centre' or X,Y in pixels, got '" + a.gaze + "'";
    return false;
  }
  d.lod.gaze_px = Eigen::Vector2d((*g)[0], (*g)[1]);
  return true;
}

// Backdrop, glossy floor and props around a model (render, view).
struct EnvArgs {
  std::string panorama, envmap, floor_map, floor_relief, up = "z";
  double floor = -1, floor_glossy = 0.5;
  std::vector<std::string> spheres;
  int envmap_size = 128;
  bool clamp = false;
};

void add_environment_options(CLI::App* sub, EnvArgs& a) {
  sub->add_option("--panorama", a.panorama, "equirectangular HDR drawn as the backdrop and reflected by glossy things");
  sub->add_option("--envmap", a.envmap, "a prebuilt environment map (s2r envmap); default: built from --panorama, only when "
                  "something is glossy");
  sub->add_option("--floor", a.floor, "a glossy floor under the object with this roughness (0 mirror .. 1 rough)")
      ->check(CLI::Range(0.0, 1.0));
  sub->add_option("--floor-roughness-map", a.floor_map, "per-pixel floor roughness from this image's first channel (4 tiles per side)");
  sub->add_option("--floor-relief", a.floor_relief, "a brick relief floor instead, R,D in Tsutsumi's 0..1000 (pattern repeats, "
                  "relief depth), drawn with material LOD (parallax occlusion near, bump mapping beyond Tsutsumi's threshold)");
  sub->add_option("--floor-glossy", a.floor_glossy, "k_g of the floor: its share of glossy reflection (0: matte, no map)")
      ->check(CLI::Range(0.0, 1.0))->capture_default_str();
  sub->add_option("--sphere", a.spheres, "a glossy sphere prop X,Y,Z,RADIUS,ROUGHNESS in world metres (repeatable)");
  sub->add_option("--up", a.up, "the world's up: z (the table frame), y, or X,Y,Z")->capture_default_str();
  sub->add_option("--envmap-size", a.envmap_size, "voxels per side of a map built here")->capture_default_str();
  sub->add_flag("--clamp-panorama", a.clamp, "clamp NaN/Inf/negative panorama pixels with a warning instead of refusing it");
}


// Empty optional: no environment asked for. An error message in `why`.
std::optional<EnvironmentSetup> environment_setup(const EnvArgs& a, std::string* why) {
  if (a.panorama.empty() && a.envmap.empty() && a.floor < 0 && a.spheres.empty() && a.floor_relief.empty()) return std::nullopt;
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
    if (!v || (*v)[0] < 0 || (*v)[0] > 1000 || (*v)[1] < 0 || (*v)[1] > 1000) {
      *why = "--floor-relief: expected R,D each in 0..1000, got '" + a.floor_relief + "'";
      return std::nullopt;
    }
    e.floor_relief_R = (*v)[0];
    e.floor_relief_D = (*v)[1];
  }
  if (a.up == "z") e.up = Eigen::Vector3d::UnitZ();
  else if (a.up == "y") e.up = Eigen::Vector3d::UnitY();
  else if (auto v = numbers(a.up, 3); v && Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]).norm() > 0) e.up = {(*v)[0], (*v)[1], (*v)[2]};
  else {
    *why = "--up: expected z, y or X,Y,Z (non-zero), got '" + a.up + "'";
    return std::nullopt;
  }
  for (const auto& sp : a.spheres) {
    auto v = numbers(sp, 5);
    if (!v || (*v)[3] <= 0 || (*v)[4] < 0 || (*v)[4] > 1) {
      *why = "--sphere: expected X,Y,Z,RADIUS,ROUGHNESS with RADIUS > 0 and ROUGHNESS in [0, 1], got '" + sp + "'";
      return std::nullopt;
    }
    e.props.push_back({{(*v)[0], (*v)[1], (*v)[2]}, (*v)[3], (*v)[4]});
  }
  return e;
}

void add_source_options(CLI::App* sub, FrameSource& s) {
  sub->add_option("--session", s.session, "the session (for frames the model does not hold, and for eval's photos)");
  sub->add_option("--poses", s.poses, "registered poses (s2r register), as given to reconstruct");
  sub->add_option("--calibration", s.calibration, "calibration, as given to reconstruct");
}

void add_render(CLI::App& app) {
  auto* sub = app.add_subcommand("render",
                                 "Offscreen image of a model (EGL) at a session frame's camera (--view I; held-out\n"
                                 "frames need --session) or a view file (--pose FILE, as the viewer's P key saves).");
  struct Args {
    std::string model, out, pose, report;
    int view = -1;
    double scale = 1;
    DrawArgs draw;
    FrameSource source;
    EnvArgs env;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("model", a->model, "model folder (s2r reconstruct)")->required();
  sub->add_option("--out", a->out, "PNG to write")->required();
  add_environment_options(sub, a->env);
  sub->add_option("--view", a->view, "session frame whose camera draws the image (0-based)");
  sub->add_option("--pose", a->pose, "view file: {format s2r.view, intrinsics, world_from_camera}");
  sub->add_option("--scale", a->scale, "image size relative to the camera's")->capture_default_str();
  sub->add_option("--report", a->report, "report path (default: beside --out)");
  add_draw_options(sub, a->draw);
  add_source_options(sub, a->source);
  sub->callback([a] {
    set_runner([a] {
      RenderJob job;
      job.model = a->model;
      job.out = a->out;
      if (a->view >= 0) job.view = a->view;
      job.view_file = a->pose;
      if (!job.view && job.view_file.empty()) return error("give --view I or --pose FILE");
      job.source = a->source;
      job.draw = draw_options(a->draw);
      if (std::string why; !apply_gaze(a->draw, job.draw, &why)) return error(why);
      job.scale = a->scale;
      std::string why;
      job.environment = environment_setup(a->env, &why);
      if (!why.empty()) return error(why);
      auto r = run_render_job(job);
      if (!r) return error(r.error().message);
      return finish(*r, a->report.empty() ? fs::path(a->out).parent_path() / "report.json" : fs::path(a->report));
    });
  });
}

void add_eval(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "eval",
      "Render frames (held out at reconstruct, or input views) and compare with the photos: PSNR and SSIM\n"
      "over the object's pixels joined with every drawn pixel, for billboards and, in the same run, the\n"
      "baselines (billboards without depth clipping, the textured patch mesh and fused surface). Writes OUT/frame_NNNN.png\n"
      "(photo | billboards | no clip | patch mesh | surface mesh), OUT/eval.csv and OUT/report.json.");
  struct Args {
    std::string model, out, holdout;
    bool no_baselines = false;
    DrawArgs draw;
    FrameSource source;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("model", a->model, "model folder (s2r reconstruct)")->required();
  sub->add_option("--holdout", a->holdout, "I,J,...: frames to render and compare")->required();
  sub->add_option("--out", a->out, "output folder (default MODEL/eval)");
  sub->add_flag("--no-baselines", a->no_baselines, "billboards only");
  add_draw_options(sub, a->draw);
  add_source_options(sub, a->source);
  sub->callback([a] {
    set_runner([a] {
      EvalJob job;
      job.model = a->model;
      job.source = a->source;
      auto frames = frame_list(a->holdout, "--holdout");
      if (!frames) return error(frames.error().message);
      job.frames = *frames;
      job.out = a->out.empty() ? fs::path(a->model) / "eval" : fs::path(a->out);
      job.draw = draw_options(a->draw);
      if (std::string why; !apply_gaze(a->draw, job.draw, &why)) return error(why);
      job.baselines = !a->no_baselines;
      auto r = run_eval_job(job);
      if (!r) return error(r.error().message);
      return finish(*r, job.out / "report.json");
    });
  });
}

void add_view(CLI::App& app) {
  auto* sub = app.add_subcommand("view", "Interactive viewer (GLFW window; the keys are listed on start and by H)");
  struct Args {
    std::string model, screenshot, pose;
    int width = 1280, height = 720, frames = 0;
    DrawArgs draw;
    EnvArgs env;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("model", a->model, "model folder (s2r reconstruct)")->required();
  sub->add_option("--width", a->width, "window width")->capture_default_str();
  sub->add_option("--height", a->height, "window height")->capture_default_str();
  sub->add_option("--pose", a->pose, "start at this view file instead of the orbit's default");
  sub->add_option("--frames", a->frames, "draw this many frames and quit (0 = until closed); for tests and timing");
  sub->add_option("--screenshot", a->screenshot, "PNG written after the last frame");
  add_draw_options(sub, a->draw);
  add_environment_options(sub, a->env);
  sub->callback([a] {
    set_runner([a] {
      ViewerOptions o;
      o.model = a->model;
      o.width = a->width;
      o.height = a->height;
      o.frames = a->frames;
      o.screenshot = a->screenshot;
      o.start_view = a->pose;
      o.draw = draw_options(a->draw);
      if (std::string why; !apply_gaze(a->draw, o.draw, &why)) return error(why);
      std::string why;
      o.environment = environment_setup(a->env, &why);
      if (!why.empty()) return error(why);
      auto r = run_viewer(o);
      if (!r) return error(r.error().message);
      std::fprintf(stderr, "%s\n", r->brief().c_str());
      return 0;
    });
  });
}

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

void add_raytrace(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "raytrace",
      "CPU ray tracer (Embree; Whitted: shadows, mirrors, refraction, Phong) with visual-field level of detail: rays get "
      "less detail, fewer bounces and coarser meshes away from the gaze, and none outside the field of view");
  struct Args {
    RaytraceJob job;
    std::string eye, gaze, out;
    bool full = false, no_compare = false;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("--scene", a->job.scene,
                  "Mochizuki and Makino's scenes, 8 Stanford bunnies and one light: A mirrors on every screen, B diffuse on every screen, "
                  "C mirrors on the front screen, D diffuse on the front screen")
      ->check(CLI::IsMember({"A", "B", "C", "D", "a", "b", "c", "d"}))->capture_default_str();
  sub->add_option("--mesh", a->job.mesh, "trace this PLY mesh instead (vertex colours used when present)");
  sub->add_option("--model", a->job.model, "trace a reconstructed model's patch mesh instead, coloured from its cameras");
  sub->add_flag("--surface", a->job.surface_mesh, "with --model: its fused surface mesh instead of the patch mesh");
  sub->add_option("--layout", a->job.layout, "cave (front, right and floor screens of a 3 m room) or view (one pinhole image); "
                  "default: cave for --scene, view for --mesh/--model")->check(CLI::IsMember({"cave", "view"}));
  sub->add_option("--eye", a->eye, "tracked eye position x,y,z in metres (default: the room's centre at 1.5 m, or in front of the object)");
  sub->add_option("--gaze", a->gaze, "gaze direction x,y,z, or forward | down | right | up (default: forward, or the view's centre)");
  sub->add_option("--size", a->job.size, "pixels per screen side (cave) or image width (view)")->capture_default_str();
  sub->add_option("--reflect-max", a->job.reflect_max, "Reflect_max: reflections/refractions at full detail")->capture_default_str();
  sub->add_flag("--full", a->full, "no visual-field LOD: every ray at full detail");
  sub->add_flag("--no-compare", a->no_compare, "skip the full-detail render used for the time ratio and the central-field PSNR");
  sub->add_option("--n-max", a->job.n_max, "N_max: triangles per object at full detail")->capture_default_str();
  sub->add_option("--n-min", a->job.n_min, "N_min: triangles per object at the coarsest level")->capture_default_str();
  sub->add_option("--levels", a->job.levels, "prebuilt mesh levels from N_max to N_min")->capture_default_str();
  sub->add_option("--threads", a->job.threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->add_option("--out", a->out, "output folder: one PNG per screen (+ cave.png unfolded), level_*.png, full_*.png, report.json")
      ->required();
  sub->callback([a] {
    set_runner([a] {
      RaytraceJob job = a->job;
      job.out = a->out;
      job.field_lod = !a->full;
      job.compare_full = !a->no_compare;
      if (!a->eye.empty()) {
        job.eye = vector3(a->eye);
        if (!job.eye || a->eye == "forward" || a->eye == "down" || a->eye == "right" || a->eye == "up")
          return error("--eye: expected x,y,z in metres, got '" + a->eye + "'");
      }
      if (!a->gaze.empty()) {
        job.gaze = vector3(a->gaze);
        if (!job.gaze) return error("--gaze: expected x,y,z or forward|down|right|up, got '" + a->gaze + "'");
      }
      auto r = run_raytrace_job(job);
      if (!r) return error(r.error().message);
      return finish(*r, fs::path(a->out) / "report.json");
    });
  });
}

void add_envmap(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "envmap",
      "Multi-scale environment map: an equirectangular HDR panorama prefiltered for every roughness, one 3D texture "
      "(direction = reflection vector, distance from the centre = smoothness lambda), checked against brute force");
  auto job = std::make_shared<EnvmapJob>();
  auto pano = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  auto report = std::make_shared<std::string>();
  sub->add_option("panorama", *pano, "equirectangular panorama (Radiance .hdr, OpenEXR, ...), linear RGB")->required();
  sub->add_option("--out", *out, "environment map to write (.exr: s x s*s, half RGB; a preview .png goes beside it)")->required();
  sub->add_option("--size", job->options.size, "s: voxels per side")->capture_default_str();
  sub->add_option("--levels", job->options.intensity_levels, "I: intensity levels the lobe must resolve (exponent at lambda 1 = g(1))")
      ->capture_default_str();
  sub->add_option("--threshold", job->options.threshold, "th: lobe weights below th times the peak are left out")->capture_default_str();
  sub->add_option("--samples-per-scale", job->options.samples_per_scale,
                  "pyramid pixels per lobe scale 1/sqrt(L): higher reads a finer panorama level")->capture_default_str();
  sub->add_option("--check", job->check, "voxels compared with the brute-force Phong lobe (0: none)")->capture_default_str();
  sub->add_option("--seed", job->seed, "which voxels are checked")->capture_default_str();
  sub->add_flag("--clamp", job->clamp, "replace NaN/negative pixels by 0 and +Inf by the largest finite value (with a warning) "
                "instead of refusing the panorama");
  sub->add_option("--threads", job->options.threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->add_option("--report", *report, "report path (default: beside --out)");
  sub->callback([=] {
    set_runner([=] {
      EnvmapJob j = *job;
      j.panorama = *pano;
      j.out = *out;
      auto r = run_envmap_job(j);
      if (!r) return error(r.error().message);
      return finish(*r, report->empty() ? fs::path(*out).parent_path() / "report.json" : fs::path(*report));
    });
  });
}

}  // namespace

void add_render_commands(CLI::App& app) {
  add_preview(app);
  add_render(app);
  add_eval(app);
  add_view(app);
  add_raytrace(app);
  add_envmap(app);
}
}  // namespace s2r::cli
