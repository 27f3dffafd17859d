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
                  "the Middlebury dino ring leave-one-out, the RealSense bear; the fit, billboards, the textured patch mesh and fused surface; full-image and "
                  "masked PSNR/SSIM, build seconds, model bytes, frame ms; views.csv, views.png)")
      ->required();
  sub->add_option("--out", a->out, "output folder")->required();
  sub->add_option("--repeats", a->repeats, "renders per point (median)")->capture_default_str();
  sub->add_option("--scene", a->scene, "rig scene for the rig sweep")->capture_default_str();
  sub->add_option("--size", a->size, "raytrace: pixels per CAVE screen side (the paper: 256; 512 steadies the timings)")->capture_default_str();
  sub->add_option("--lego-views", a->lego_views, "views: lego val views evaluated, evenly spaced (100 = all)")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  sub->add_option("--fit", a->fit.lego, "views: seconds of lego's fit (its PSNR at 1, 5, 10, 15, 20 minutes on the way, fit.png); 0: no fit")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--scenes", a->scenes, "views: the scenes to run, of lego, bunny, fuzzy, dino, bear (default all)")
      ->delimiter(',')
      ->check(CLI::IsMember({"lego", "bunny", "fuzzy", "dino", "bear"}));
  sub->add_option("--fit-others", a->fit.others, "views: seconds of the other scenes' fits; 0: no fit")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  sub->add_option("--fit-ssim", a->fit.ssim, "views: the fits' loss, (1 - W) x the colour term + W x (1 - SSIM) (reconstruct --fit-ssim)")
      ->check(CLI::Range(0.0, 0.95))
      ->capture_default_str();
  sub->add_option("--fit-loss", a->fit.loss, "views: the fits' colour term, l2 or l1 (reconstruct --fit-loss)")
      ->check(CLI::IsMember({"l2", "l1"}))
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

void add_batch(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand(
      "batch",
      "Many captures through the same steps, here or as a Slurm job array. Every capture under ROOT (a session\n"
      "folder, or a data set with an importer) runs import, calibrate, register, reconstruct, eval (and export)\n"
      "as needed, each step its own s2r process, results in OUT/<capture>/; OUT/index.html has a row per capture,\n"
      "failures first. Run it again to resume: finished steps whose outputs validate are skipped.");
  auto a = std::make_shared<BatchArgs>();
  sub->add_option("root", a->root, "folder of captures (or one capture); default: the root OUT/batch.json names");
  sub->add_option("--out", a->out, "results folder");
  sub->add_option("--steps", a->steps, "steps to run, in pipeline order: import, calibrate, register, reconstruct, eval, "
                                       "export")->capture_default_str();
  sub->add_option("--options", a->options, "JSON options file, the same for every capture (holdout, heldout_views, "
                                           "export, and each step's extra arguments; docs/cli.md)");
  sub->add_option("--jobs", a->jobs, "captures run at once on this machine")->capture_default_str()->check(CLI::Range(1, 256));
  sub->add_flag("--retry-failed", a->retry_failed, "run again only the captures that failed");
  sub->add_option("--status", a->status, "RESULTS: what finished, read from its files; writes RESULTS/index.html "
                                         "(exit 0: all done, 1: failures, 3: some not finished)");
  sub->add_flag("--slurm", a->slurm, "submit a Slurm job array (a task per capture) and a summary job after it");
  sub->add_option("--partition", a->partition, "--slurm: sbatch --partition");
  sub->add_option("--time", a->time, "--slurm: time limit per task (sbatch --time; default from measured step seconds)");
  sub->add_option("--mem", a->mem_mb, "--slurm: MB per task (default from the steps' measured peaks)");
  sub->add_option("--cpus-per-task", a->cpus_per_task, "--slurm: cores per task")->capture_default_str()->check(CLI::Range(1, 4096));
  sub->add_option("--sbatch-arg", a->sbatch_args, "--slurm: an extra sbatch argument, passed through (repeat it)")
      ->allow_extra_args(false);
  sub->add_option("--sbatch", a->sbatch, "--slurm: the sbatch program")->capture_default_str();
  sub->add_option("--task", a->task, "run array task I of --tasks (what the --slurm script runs)");
  sub->add_option("--tasks", a->tasks, "the array's size");
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
  add_batch(app, chosen);
}

std::optional<int> parse_command_line(int argc, char** argv, Chosen& chosen, bool& quiet) {
  CLI::App app;
  add_commands(app, chosen, quiet);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version are success; every other parse error is a usage
    // error: exit 2, as docs/cli.md says (CLI11's own codes are 101-127).
    return app.exit(e) == 0 ? 0 : 2;
  }
  return std::nullopt;
}

}  // namespace s2r::cli
