// Subcommands that make or transform data: synth, import, and the stages'
// entry points that later work fills in.
#include <cstdio>

#include "app/commands.h"
#include "capture/import_datasets.h"
#include "capture/session.h"
#include "capture/synth_rig.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {

void add_synth(CLI::App& app) {
  auto* sub = app.add_subcommand("synth", "Synthetic turntable rig with ground truth (session + ground_truth/)");
  auto o = std::make_shared<SynthOptions>();
  auto out = std::make_shared<std::string>();
  auto report = std::make_shared<std::string>();
  sub->add_option("--scene", o->scene, "bunny | fuzzy | room | blob")->capture_default_str();
  sub->add_option("--views", o->views, "turntable steps over 360 degrees")->capture_default_str();
  sub->add_option("--seed", o->seed, "noise seed (same seed, same bytes)")->capture_default_str();
  sub->add_option("--out", *out, "session folder to create")->required();
  sub->add_option("--width", o->width, "image width (intrinsics scale with it)")->capture_default_str();
  sub->add_option("--height", o->height, "image height")->capture_default_str();
  sub->add_option("--spp", o->spp, "colour samples per pixel (1 or 4)")->capture_default_str();
  sub->add_option("--depth-noise", o->depth_noise_k, "depth sigma = k z^2 (m)")->capture_default_str();
  sub->add_option("--exposure", o->exposure, "colour gain (clips above 1)")->capture_default_str();
  sub->add_option("--color-noise", o->color_noise, "colour noise sigma, 8-bit levels")->capture_default_str();
  sub->add_option("--dropout", o->dropout, "random depth hole probability")->capture_default_str();
  sub->add_option("--grazing-deg", o->grazing_deg, "no depth beyond this incidence angle")->capture_default_str();
  sub->add_option("--table-error-deg", o->table_error_deg, "table turns this much less per step")->capture_default_str();
  sub->add_option("--threads", o->threads, "0 = all cores")->capture_default_str();
  sub->add_option("--data", o->data_dir, "real data folder (default $S2R_DATA or ../shared/data)");
  sub->add_option("--report", *report, "report path (default OUT/report.json)");
  sub->callback([=] {
    set_runner([=] {
      auto r = synth_session(*o, *out);
      if (!r) return error(r.error().message);
      return finish(*r, report->empty() ? fs::path(*out) / "report.json" : fs::path(*report));
    });
  });
}

void add_import(CLI::App& app) {
  auto* sub = app.add_subcommand("import", "Turn a real data set into a session");
  auto kind = std::make_shared<std::string>();
  auto path = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  auto report = std::make_shared<std::string>();
  auto o = std::make_shared<ImportOptions>();
  sub->add_option("kind", *kind, "stanford | middlebury | realsense | 7scenes")
      ->required()->check(CLI::IsMember({"stanford", "middlebury", "realsense", "7scenes"}));
  sub->add_option("path", *path, "stanford: the .conf; others: the data folder")->required();
  sub->add_option("--out", *out, "session folder to create")->required();
  sub->add_option("--stride", o->stride, "take every n-th view")->capture_default_str();
  sub->add_option("--max-frames", o->max_frames, "0 = all")->capture_default_str();
  sub->add_option("--report", *report, "report path (default OUT/report.json)");
  sub->callback([=] {
    set_runner([=] {
      auto r = import_dataset(*kind, *path, *out, *o);
      if (!r) return error(r.error().message);
      return finish(*r, report->empty() ? fs::path(*out) / "report.json" : fs::path(*report));
    });
  });
}

void add_inspect(CLI::App& app) {
  auto* sub = app.add_subcommand("inspect", "Validate a session and print a summary");
  auto path = std::make_shared<std::string>();
  auto decode = std::make_shared<bool>(false);
  sub->add_option("session", *path, "session folder")->required();
  sub->add_flag("--decode", *decode, "also decode every image (finds truncated files)");
  sub->callback([=] {
    set_runner([=] {
      auto s = load_session(*path);
      if (!s) return error(s.error().message);
      std::printf("session %s (%s): %zu frames, layout %s\n", s->name.c_str(), s->source.c_str(),
                  s->frames.size(), s->layout == Layout::kObjectCentre ? "object_centre" : "camera_centre");
      if (s->color)
        std::printf("  colour: %s %dx%d fx %.2f fy %.2f\n", s->color->driver.c_str(), s->color->intrinsics.width,
                    s->color->intrinsics.height, s->color->intrinsics.fx, s->color->intrinsics.fy);
      if (s->depth) std::printf("  depth: %s unit %.4g m\n", s->depth->driver.c_str(), s->depth->unit_m);
      if (*decode)
        for (const auto& f : s->frames) {
          if (!f.color.empty())
            if (auto c = load_color(*s, f); !c) return error(c.error().message);
          if (!f.depth.empty())
            if (auto d = load_depth(*s, f); !d) return error(d.error().message);
        }
      std::printf("ok\n");
      return 0;
    });
  });
}

}  // namespace

void add_data_commands(CLI::App& app) {
  add_synth(app);
  add_import(app);
  add_inspect(app);
  add_not_yet(app, "devices", "List cameras, depth nodes and serial ports");
  add_not_yet(app, "capture", "Run a capture session (--sim | --replay | real devices)");
  add_not_yet(app, "calibrate", "Intrinsics, depth-to-colour, turntable axis");
  add_not_yet(app, "register", "Register all views at once");
  add_not_yet(app, "reconstruct", "Fusion, microfacets, octree, per-camera depth");
}

}  // namespace s2r::cli
