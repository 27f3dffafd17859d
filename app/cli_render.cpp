// Flags of the subcommands that draw: preview, render, eval, view, raytrace,
// envmap (run by app/cmd_render.cpp).
#include "app/cli.h"

namespace s2r::cli {

namespace {

void add_preview(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("preview", "Offscreen image of a session's depth as coloured points, from one view's camera");
  auto a = std::make_shared<PreviewArgs>();
  PreviewOptions& o = a->options;
  sub->add_option("session", a->session, "session folder")->required();
  sub->add_option("--out", a->out, "PNG to write (also writes *_compare.png: photo | preview)")->required();
  sub->add_option("--view", o.view, "frame whose camera draws the image (0-based)")->capture_default_str();
  sub->add_option("--stride", o.stride, "use every n-th depth pixel")->capture_default_str();
  sub->add_option("--point-size", o.point_size, "splat size in pixels (0 = auto)")->capture_default_str();
  sub->add_flag("--single-view", o.single_view, "only the chosen view's own depth");
  sub->add_option("--report", a->report, "report path (default: beside --out)");
  sub->callback([a, &chosen] { chosen = a; });
}

// The drawing flags every model command shares, bound straight to
// DrawOptions: each default is the renderer's own.
void add_draw_options(CLI::App* sub, DrawArgs& a) {
  DrawOptions& d = a.d;
  sub->add_option("--geometry", a.geometry, "billboards | mesh (the octree's patch mesh, textured) | surface (the fused surface mesh, textured) | fitted (the billboards fitted to the photos, reconstruct --fit) | auto (fitted where the model has a fit, else billboards)")
      ->check(CLI::IsMember({"auto", "billboards", "mesh", "surface", "fitted"}))->capture_default_str();
  sub->add_option("--fitted-pass", a.fitted_pass, "fitted: where the billboards are composited: cpu (front to back, each pixel "
                  "stopping at its first opaque layer), gl, or auto (cpu when OpenGL itself runs on the CPU: llvmpipe, "
                  "softpipe, SwiftShader; else gl)")
      ->check(CLI::IsMember({"auto", "cpu", "gl"}))->capture_default_str();
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

void add_source_options(CLI::App* sub, FrameSource& s) {
  sub->add_option("--session", s.session, "the session (for frames the model does not hold, and for eval's photos)");
  sub->add_option("--poses", s.poses, "registered poses (s2r register), as given to reconstruct");
  sub->add_option("--calibration", s.calibration, "calibration, as given to reconstruct");
}

void add_render(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("render",
                                 "Offscreen image of a model (EGL) at a session frame's camera (--view I; held-out\n"
                                 "frames need --session) or a view file (--pose FILE, as the viewer's P key saves).");
  auto a = std::make_shared<RenderArgs>();
  RenderJob& job = a->job;
  sub->add_option("model", job.model, "model folder (s2r reconstruct)")->required();
  sub->add_option("--out", job.out, "PNG to write")->required();
  add_environment_options(sub, a->env);
  sub->add_option("--view", a->view, "session frame whose camera draws the image (0-based)");
  sub->add_option("--pose", job.view_file, "view file: {format s2r.view, intrinsics, world_from_camera}");
  sub->add_option("--scale", job.scale, "image size relative to the camera's")->capture_default_str();
  sub->add_option("--background", a->background, "white, black or R,G,B (0-255 levels); default: the model's own background (the capture's, e.g. white for NeRF-synthetic), else black");
  sub->add_flag_callback("--no-backdrop-plate", [&job] { job.backdrop_plate = false; },
                         "a frame of the model's own capture on the background colour, not on the capture's backdrop plate");
  sub->add_option("--report", a->report, "report path (default: beside --out)");
  add_draw_options(sub, a->draw);
  add_source_options(sub, job.source);
  sub->callback([a, &chosen] { chosen = a; });
}

void add_eval(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "eval",
      "Render frames (held out at reconstruct, or input views) and compare with the photos: PSNR and SSIM\n"
      "over the object's pixels joined with every drawn pixel, for billboards and, in the same run, the\n"
      "baselines (billboards without depth clipping, the textured patch mesh and fused surface). Writes OUT/frame_NNNN.png\n"
      "(photo | fitted billboards, where the model has a fit | billboards | no clip | patch mesh | surface mesh), OUT/eval.csv and OUT/report.json.");
  auto a = std::make_shared<EvalArgs>();
  EvalJob& job = a->job;
  sub->add_option("model", job.model, "model folder (s2r reconstruct)")->required();
  sub->add_option("--holdout", a->holdout, "I,J,...: frames to render and compare")->required();
  sub->add_option("--out", a->out, "output folder (default MODEL/eval)");
  sub->add_flag_callback("--no-baselines", [&job] { job.baselines = false; }, "billboards (and fitted billboards) only");
  sub->add_option("--splats", job.splats, "draw this snapshot of the fit as 'fitted' (splats_<S>s.bin, reconstruct --fit-snapshots)");
  sub->add_option("--background", a->background, "white, black or R,G,B (0-255 levels); default: the session's own background, else the backdrop's colour, else black");
  sub->add_flag_callback("--no-backdrop-plate", [&job] { job.backdrop_plate = false; },
                         "frames of the model's own capture on the background colour, not on the capture's backdrop plate");
  add_draw_options(sub, a->draw);
  add_source_options(sub, job.source);
  sub->callback([a, &chosen] { chosen = a; });
}

void add_view(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("view", "Interactive viewer (GLFW window; the keys are listed on start and by H)");
  auto a = std::make_shared<ViewArgs>();
  ViewerOptions& o = a->options;
  sub->add_option("model", o.model, "model folder (s2r reconstruct)")->required();
  sub->add_option("--width", o.width, "window width")->capture_default_str();
  sub->add_option("--height", o.height, "window height")->capture_default_str();
  sub->add_option("--pose", o.start_view, "start at this view file instead of the orbit's default");
  sub->add_option("--frames", o.frames, "draw this many frames and quit (0 = until closed); for tests and timing")
      ->capture_default_str();
  sub->add_option("--screenshot", o.screenshot, "PNG written after the last frame");
  sub->add_option("--turn", o.orbit_deg_per_frame, "turn the orbit this many degrees a frame (timing a moving view with --frames)")
      ->check(CLI::Range(0.0, 360.0))->capture_default_str();
  add_draw_options(sub, a->draw);
  add_environment_options(sub, a->env);
  sub->callback([a, &chosen] { chosen = a; });
}

void add_raytrace(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "raytrace",
      "CPU ray tracer (Embree; Whitted: shadows, mirrors, refraction, Phong) with visual-field level of detail: rays get "
      "less detail, fewer bounces and coarser meshes away from the gaze, and none outside the field of view");
  auto a = std::make_shared<RaytraceArgs>();
  RaytraceJob& job = a->job;
  sub->add_option("--scene", job.scene,
                  "Mochizuki and Makino's scenes, 8 Stanford bunnies and one light: A mirrors on every screen, B diffuse on every screen, "
                  "C mirrors on the front screen, D diffuse on the front screen")
      ->check(CLI::IsMember({"A", "B", "C", "D", "a", "b", "c", "d"}))->capture_default_str();
  sub->add_option("--mesh", job.mesh, "trace this PLY mesh instead (vertex colours used when present)");
  sub->add_option("--model", job.model, "trace a reconstructed model's patch mesh instead, coloured from its cameras");
  sub->add_flag("--surface", job.surface_mesh, "with --model: its fused surface mesh instead of the patch mesh");
  sub->add_option("--layout", job.layout, "cave (front, right and floor screens of a 3 m room) or view (one pinhole image); "
                  "default: cave for --scene, view for --mesh/--model")->check(CLI::IsMember({"cave", "view"}));
  sub->add_option("--eye", a->eye, "tracked eye position x,y,z in metres (default: the room's centre at 1.5 m, or in front of the object)");
  sub->add_option("--gaze", a->gaze, "gaze direction x,y,z, or forward | down | right | up (default: forward, or the view's centre)");
  sub->add_option("--size", job.size, "pixels per screen side (cave) or image width (view)")->capture_default_str();
  sub->add_option("--reflect-max", job.reflect_max, "Reflect_max: reflections/refractions at full detail")->capture_default_str();
  sub->add_flag("--full", a->full, "no visual-field LOD: every ray at full detail");
  sub->add_flag("--no-compare", a->no_compare, "skip the full-detail render used for the time ratio and the central-field PSNR");
  sub->add_option("--n-max", job.n_max, "N_max: triangles per object at full detail")->capture_default_str();
  sub->add_option("--n-min", job.n_min, "N_min: triangles per object at the coarsest level")->capture_default_str();
  sub->add_option("--levels", job.levels, "prebuilt mesh levels from N_max to N_min")->capture_default_str();
  sub->add_option("--threads", job.threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->add_option("--out", a->out, "output folder: one PNG per screen (+ cave.png unfolded), level_*.png, full_*.png, report.json")
      ->required();
  sub->callback([a, &chosen] { chosen = a; });
}

void add_envmap(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "envmap",
      "Multi-scale environment map: an equirectangular HDR panorama prefiltered for every roughness, one 3D texture "
      "(direction = reflection vector, distance from the centre = smoothness lambda), checked against brute force");
  auto a = std::make_shared<EnvmapArgs>();
  EnvmapJob& job = a->job;
  sub->add_option("panorama", job.panorama, "equirectangular panorama (Radiance .hdr, OpenEXR, ...), linear RGB")->required();
  sub->add_option("--out", job.out, "environment map to write (.exr: s x s*s, half RGB; a preview .png goes beside it)")->required();
  sub->add_option("--size", job.options.size, "s: voxels per side")->capture_default_str();
  sub->add_option("--levels", job.options.intensity_levels, "I: intensity levels the lobe must resolve (exponent at lambda 1 = g(1))")
      ->capture_default_str();
  sub->add_option("--threshold", job.options.threshold, "th: lobe weights below th times the peak are left out")->capture_default_str();
  sub->add_option("--samples-per-scale", job.options.samples_per_scale,
                  "pyramid pixels per lobe scale 1/sqrt(L): higher reads a finer panorama level")->capture_default_str();
  sub->add_option("--check", job.check, "voxels compared with the brute-force Phong lobe (0: none)")->capture_default_str();
  sub->add_option("--seed", job.seed, "which voxels are checked")->capture_default_str();
  sub->add_flag("--clamp", job.clamp, "replace NaN/negative pixels by 0 and +Inf by the largest finite value (with a warning) "
                "instead of refusing the panorama");
  sub->add_option("--threads", job.options.threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->add_option("--report", a->report, "report path (default: beside --out)");
  sub->callback([a, &chosen] { chosen = a; });
}

}  // namespace

void add_render_commands(CLI::App& app, Chosen& chosen) {
  add_preview(app, chosen);
  add_render(app, chosen);
  add_eval(app, chosen);
  add_view(app, chosen);
  add_raytrace(app, chosen);
  add_envmap(app, chosen);
}

}  // namespace s2r::cli
