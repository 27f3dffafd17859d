// The command line's top level, and the flags of bench and summary (run by
// app/cmd_bench.cpp and app/cmd_summary.cpp).
#include "app/cli.h"

namespace s2r::cli {

namespace {

void add_bench(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("bench", "Error-vs-time sweeps: CSV + PNG plot + report.json, peers in the same run");
  auto a = std::make_shared<BenchArgs>();
  sub->add_option("stage", a->stage, "rig (render time vs image size), capture (per-frame decode + write overhead), calibrate (error vs views), "
                  "register (Stanford bunny ring-scan pose error vs seconds: ours on all ten scans and on the ring alone, against PCL ICP chained around the ring; --repeats = seeds), "
                  "reconstruct (surface error and build seconds vs facet size on the rig, against Open3D TSDF + marching cubes), "
                  "render (held-out PSNR vs 1280x720 frame ms per drawing setting, rig bunny and fuzzy, textured meshes in the same run), "
                  "raytrace (Mochizuki and Makino's four CAVE scenes: visual-field LOD time vs the full render, gaze forward and down, PSNR inside "
                  "the central field and over all pixels), envmap (environment map error against brute-force Phong vs build seconds "
                  "and memory, per size, weight threshold and pyramid resolution; every bundled panorama; a GL glossy sphere against the ray "
                  "tracer), material (texture / bump / parallax occlusion mapping switched per pixel by Tsutsumi's thresholds, "
                  "frame time and PSNR against parallax everywhere, on a board and a roof model), "
                  "views (held-out views as the field measures them: lego val on white fitted on train, the rig bunny and fuzzy, "
                  "the Middlebury dino ring leave-one-out, the RealSense bear; billboards and the textured patch mesh; full-image and "
                  "masked PSNR/SSIM, build seconds, model bytes, frame ms; views.csv, views.png)")
      ->required();
  sub->add_option("--out", a->out, "output folder")->required();
  sub->add_option("--repeats", a->repeats, "renders per point (median)")->capture_default_str();
  sub->add_option("--scene", a->scene, "rig scene for the rig sweep")->capture_default_str();
  sub->add_option("--size", a->size, "raytrace: pixels per CAVE screen side (the paper: 256; 512 steadies the timings)")->capture_default_str();
  sub->add_option("--lego-views", a->lego_views, "views: lego val views evaluated, evenly spaced (100 = all)")
      ->capture_default_str();
  sub->add_option("--fit", a->fit_lego, "views: seconds of lego's fit (its PSNR at 1, 5, 10, 15, 20 minutes on the way, fit.png); 0: no fit")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--scenes", a->scenes, "views: the scenes to run, of lego, bunny, fuzzy, dino, bear (default all)")
      ->delimiter(',')
      ->check(CLI::IsMember({"lego", "bunny", "fuzzy", "dino", "bear"}));
  sub->add_option("--fit-others", a->fit_others, "views: seconds of the other scenes' fits; 0: no fit")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--voxels", a->voxels, "envmap: voxels checked against brute force at the default setting (a tenth elsewhere)")
      ->capture_default_str();
  sub->callback([a, &chosen] { chosen = a; });
}

void add_summary(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("summary",
                                 "One page for a run's folder: every report.json as a table, held-out error against "
                                 "frame time, every PNG (writes FOLDER/index.html and index.md)");
  auto a = std::make_shared<SummaryArgs>();
  sub->add_option("folder", a->folder, "folder the run wrote (searched recursively)")->required();
  sub->add_option("--title", a->title, "page title");
  sub->callback([a, &chosen] { chosen = a; });
}

}  // namespace

void add_commands(CLI::App& app, Chosen& chosen, bool& quiet) {
  app.description(
      "s2r - scan2render: turntable capture -> calibration -> reconstruction -> rendering.\n"
      "Every computing subcommand writes report.json (errors, counts, skipped work, seconds).");
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "every subcommand's options, on one page");
  app.add_flag("-q,--quiet", quiet, "no progress bars");
  add_data_commands(app, chosen);
  add_reconstruct_commands(app, chosen);
  add_render_commands(app, chosen);
  add_bench(app, chosen);
  add_summary(app, chosen);
}

std::optional<int> parse_command_line(int argc, char** argv, Chosen& chosen, bool& quiet) {
  CLI::App app;
  add_commands(app, chosen, quiet);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  return std::nullopt;
}

}  // namespace s2r::cli
