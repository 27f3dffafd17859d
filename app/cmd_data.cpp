// Subcommands that make or transform data: synth, import, and the stages'
// entry points that later work fills in.
#include <cstdio>

#include "app/commands.h"
#include <csignal>

#include <glob.h>

#include "calibrate/depth_to_color.h"
#include "calibrate/intrinsics.h"
#include "calibrate/table_markers.h"
#include "calibrate/turntable_axis.h"
#include "capture/capture_devices.h"
#include "capture/capture_session.h"
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

std::atomic<bool> g_stop{false};
extern "C" void on_stop_signal(int) { g_stop = true; }

// "camera-vanish@5" -> the fault, at the 5th frame / line.
Status apply_sim_fault(const std::string& spec, SimOptions& sim) {
  const size_t at = spec.find('@');
  if (at == std::string::npos) return fail("--sim-fault wants KIND@N, got '" + spec + "'");
  const std::string kind = spec.substr(0, at);
  int n = 0;
  try {
    n = std::stoi(spec.substr(at + 1));
  } catch (...) {
    return fail("--sim-fault: '" + spec.substr(at + 1) + "' is not a number");
  }
  if (kind == "camera-vanish") sim.color_faults.vanish_at = n;
  else if (kind == "depth-vanish") sim.depth_faults.vanish_at = n;
  else if (kind == "camera-timeout") sim.color_faults.timeout_at = n;
  else if (kind == "eagain-storm") { sim.color_faults.eagain_storm_at = n; sim.color_faults.eagain_count = 1000; }
  else if (kind == "serial-silent") sim.table_faults.silent_after = n;
  else if (kind == "table-alarm") sim.table_faults.alarm_at = n;
  else if (kind == "drop-ok") sim.table_faults.drop_ok_at = n;
  else if (kind == "table-reset") sim.table_faults.reset_mid_move_at = n;
  else return fail("--sim-fault: unknown kind '" + kind + "' (camera-vanish, depth-vanish, camera-timeout, "
                   "eagain-storm, serial-silent, table-alarm, drop-ok, table-reset)");
  return {};
}

void add_capture(CLI::App& app) {
  auto* sub = app.add_subcommand("capture", "Run a turntable capture session (simulated, replayed or real devices)");
  struct Args {
    std::string out, replay, camera, depth, turntable, record, report, scene = "blob";
    bool sim = false, resume = false;
    int steps = 24, width = 640, height = 480, settle_ms = 300, flush = -1;
    uint64_t seed = 7;
    std::vector<std::string> faults;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("--out", a->out, "session folder")->required();
  sub->add_option("--steps", a->steps, "turntable steps over 360 degrees")->capture_default_str();
  sub->add_flag("--resume", a->resume, "continue a session that was interrupted or killed");
  auto* sim = sub->add_flag("--sim", a->sim, "simulated rig: real V4L2/GRBL driver code over simulated devices");
  auto* rep = sub->add_option("--replay", a->replay, "replay a recording folder (color.v4l2rec, depth.v4l2rec, turntable.transcript)");
  auto* cam = sub->add_option("--camera", a->camera, "colour camera: /dev/videoN or libcamera:ID");
  sub->add_option("--depth", a->depth, "depth camera node (UVC Z16), optional");
  auto* tty = sub->add_option("--turntable", a->turntable, "serial port of the GRBL turntable, e.g. /dev/ttyUSB0");
  sim->excludes(rep)->excludes(cam);
  rep->excludes(cam);
  cam->needs(tty);
  sub->add_option("--record", a->record, "also record the device boundaries into this folder");
  sub->add_option("--width", a->width, "image width")->capture_default_str();
  sub->add_option("--height", a->height, "image height")->capture_default_str();
  sub->add_option("--settle-ms", a->settle_ms, "wait after the table stops")->capture_default_str();
  sub->add_option("--flush", a->flush, "colour frames dropped after each move (default: 2 real, 0 sim/replay)");
  sub->add_option("--scene", a->scene, "--sim: rig scene (bunny, fuzzy, room, blob)")->capture_default_str();
  sub->add_option("--seed", a->seed, "--sim: noise seed")->capture_default_str();
  sub->add_option("--sim-fault", a->faults, "--sim: inject KIND@N (camera-vanish, depth-vanish, camera-timeout, "
                                            "eagain-storm, serial-silent, table-alarm, drop-ok, table-reset)");
  sub->add_option("--report", a->report, "report path (default OUT/report.json)");
  sub->callback([a] {
    set_runner([a] {
      if (!a->sim && a->replay.empty() && a->camera.empty())
        return error("choose the devices: --sim, --replay DIR, or --camera DEV --turntable TTY");
      // From here on SIGINT/SIGTERM end the session cleanly between frames.
      struct sigaction sa {};
      sa.sa_handler = on_stop_signal;
      sigaction(SIGINT, &sa, nullptr);
      sigaction(SIGTERM, &sa, nullptr);
      DeviceOptions d;
      d.width = a->width;
      d.height = a->height;
      d.settle = std::chrono::milliseconds(a->settle_ms);
      d.record_dir = a->record;
      Result<std::unique_ptr<CaptureRig>> rig = fail("no devices");
      if (a->sim) {
        SimOptions so;
        so.scene = a->scene;
        so.seed = a->seed;
        for (const auto& f : a->faults)
          if (auto st = apply_sim_fault(f, so); !st) return error(st.error().message);
        rig = make_sim_capture(so, d);
      } else if (!a->replay.empty()) {
        rig = make_replay_capture(a->replay, d);
      } else {
        rig = make_hardware_capture(a->camera, a->depth, a->turntable, d);
      }
      if (!rig) return error(rig.error().message);
      CaptureOptions o;
      o.out = a->out;
      o.steps = a->steps;
      o.resume = a->resume;
      o.flush_frames = a->flush >= 0 ? a->flush : (a->sim || !a->replay.empty() ? 0 : 2);
      auto r = run_capture((*rig)->devices, o, &g_stop);
      if (!r) {
        std::fprintf(stderr, "s2r: error: %s\n", r.error().message.c_str());
        if (fs::exists(fs::path(a->out) / "session.json"))
          std::fprintf(stderr, "s2r: the session keeps every complete frame; continue with: s2r capture --out %s --resume ...\n",
                       a->out.c_str());
        return g_stop ? 130 : 1;
      }
      return finish(*r, a->report.empty() ? fs::path(a->out) / "report.json" : fs::path(a->report));
    });
  });
}

std::vector<fs::path> expand_glob(const std::string& pattern) {
  std::vector<fs::path> out;
  glob_t g{};
  if (::glob(pattern.c_str(), 0, nullptr, &g) == 0)
    for (size_t i = 0; i < g.gl_pathc; ++i) out.emplace_back(g.gl_pathv[i]);
  globfree(&g);
  return out;
}

// Each calibrate command adds its part to the file and keeps the others.
Calibration existing_calibration(const std::string& path) {
  if (fs::exists(path))
    if (auto old = load_calibration(path)) return *old;
  return {};
}

void add_calibrate_markers(CLI::App* cal);

void add_calibrate(CLI::App& app) {
  auto* cal = app.add_subcommand("calibrate", "Camera intrinsics, depth-to-colour, turntable axis");
  cal->require_subcommand(1);
  auto* in = cal->add_subcommand("intrinsics", "Intrinsics from chessboard or ChArUco photos (OpenCV)");
  struct Args {
    std::string images, board, out, report;
    double reject = 3.0;
    bool fix_k3 = false;
  };
  auto a = std::make_shared<Args>();
  in->add_option("--images", a->images, "glob of board photos, e.g. 'calib/*.jpg'")->required();
  in->add_option("--board", a->board, "chessboard:COLSxROWS:SQUARE_M or charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]")
      ->required();
  in->add_option("--out", a->out, "calibration file to write (JSON, s2r.calibration)")->required();
  in->add_option("--reject-factor", a->reject, "drop a view whose RMS exceeds this x the median")->capture_default_str();
  in->add_flag("--fix-k3", a->fix_k3, "keep k3 = 0 (most lenses; steadier with few or central views)");
  in->add_option("--report", a->report, "report path (default: beside --out)");
  in->callback([a] {
    set_runner([a] {
      auto board = BoardSpec::parse(a->board);
      if (!board) return error(board.error().message);
      const auto files = expand_glob(a->images);
      if (files.empty()) return error("no file matches '" + a->images + "'");
      IntrinsicsOptions o;
      o.board = *board;
      o.reject_factor = a->reject;
      o.fix_k3 = a->fix_k3;
      auto r = calibrate_intrinsics_from_files(files, o);
      if (!r) return error(r.error().message);
      for (const auto& v : r->views)
        std::printf("%-24s %s %s\n", v.name.c_str(),
                    v.used ? ("rms " + std::to_string(v.rms_px) + " px").c_str() : "not used", v.note.c_str());
      const auto& K = r->calibration.intrinsics;
      std::printf("fx %.3f +- %.3f  fy %.3f +- %.3f  cx %.3f +- %.3f  cy %.3f +- %.3f\n", K.fx, r->stddev[0], K.fy,
                  r->stddev[1], K.cx, r->stddev[2], K.cy, r->stddev[3]);
      std::printf("dist %.5f %.5f %.5f %.5f %.5f   RMS %.4f px over %d views\n", K.dist[0], K.dist[1], K.dist[2],
                  K.dist[3], K.dist[4], r->calibration.rms_px, r->calibration.views);
      Calibration c = existing_calibration(a->out);
      c.color = r->calibration;
      if (auto st = save_calibration(a->out, c); !st) return error(st.error().message);
      return finish(r->report, a->report.empty() ? fs::path(a->out).parent_path() / "report.json" : fs::path(a->report));
    });
  });
  auto* dc = cal->add_subcommand("depth", "Depth-to-colour extrinsic from a board seen by both cameras");
  auto dargs = std::make_shared<std::array<std::string, 3>>();  // session, board, out
  (*dargs)[1] = "chessboard:9x6:0.02";
  dc->add_option("session", (*dargs)[0], "session with colour and depth frames of a board")->required();
  dc->add_option("--board", (*dargs)[1], "board spec")->capture_default_str();
  dc->add_option("--out", (*dargs)[2], "calibration file to write (the extrinsic is added)")->required();
  dc->callback([dargs] {
    set_runner([dargs] {
      auto board = BoardSpec::parse((*dargs)[1]);
      if (!board) return error(board.error().message);
      auto s = load_session((*dargs)[0]);
      if (!s) return error(s.error().message);
      if (!s->color || !s->depth) return error("the session needs a colour and a depth sensor");
      Calibration c = existing_calibration((*dargs)[2]);
      const Intrinsics Kc = c.color ? c.color->intrinsics : s->color->intrinsics;
      std::vector<DepthColorView> views;
      for (const auto& f : s->frames) {
        if (f.color.empty() || f.depth.empty()) continue;
        auto im = load_color(*s, f);
        if (!im) return error(im.error().message);
        auto d = load_depth(*s, f);
        if (!d) return error(d.error().message);
        auto det = detect_board(*im, *board);
        if (!det) return error(det.error().message);
        views.push_back({std::move(*det), std::move(*d), f.depth});
      }
      auto r = calibrate_depth_to_color(views, Kc, s->depth->intrinsics, s->depth->unit_m, s->depth->color_from_depth);
      if (!r) return error(r.error().message);
      c.color_from_depth = r->color_from_depth;
      c.color_from_depth_rms = r->rms_m;
      if (auto st = save_calibration((*dargs)[2], c); !st) return error(st.error().message);
      return finish(r->report, fs::path((*dargs)[2]).parent_path() / "report.json");
    });
  });
  auto* ax = cal->add_subcommand("axis", "Turntable axis from board views at known table angles (Ceres)");
  struct AxisArgs {
    std::string session, board = "chessboard:9x6:0.02", out, intrinsics, report;
  };
  auto b = std::make_shared<AxisArgs>();
  ax->add_option("session", b->session, "session whose frames show a board standing on the table")->required();
  ax->add_option("--board", b->board, "board spec")->capture_default_str();
  ax->add_option("--out", b->out, "calibration file to write (the axis is added to what it holds)")->required();
  ax->add_option("--intrinsics", b->intrinsics, "calibration file with the colour intrinsics (default: the session's)");
  ax->add_option("--report", b->report, "report path (default: beside --out)");
  ax->callback([b] {
    set_runner([b] {
      auto board = BoardSpec::parse(b->board);
      if (!board) return error(board.error().message);
      auto s = load_session(b->session);
      if (!s) return error(s.error().message);
      Calibration c = existing_calibration(b->out);
      std::optional<Intrinsics> K;
      if (!b->intrinsics.empty()) {
        auto ic = load_calibration(b->intrinsics);
        if (!ic) return error(ic.error().message);
        if (!ic->color) return error(b->intrinsics + ": no colour intrinsics in it");
        K = ic->color->intrinsics;
        c.color = ic->color;
      } else if (c.color) {
        K = c.color->intrinsics;
      } else if (s->color) {
        K = s->color->intrinsics;
      }
      if (!K) return error("no intrinsics: pass --intrinsics CALIB");
      std::vector<AxisView> views;
      for (const auto& f : s->frames) {
        if (f.color.empty()) continue;
        auto im = load_color(*s, f);
        if (!im) return error(im.error().message);
        auto d = detect_board(*im, *board);
        if (!d) return error(d.error().message);
        views.push_back({f.table_angle_commanded_deg, std::move(*d), f.color});
      }
      auto r = calibrate_turntable_axis(views, *K);
      if (!r) return error(r.error().message);
      const auto& a = r->axis;
      std::printf("axis direction (camera) %.6f %.6f %.6f  point %.5f %.5f %.5f m  RMS %.3f px\n",
                  a.direction_camera.x(), a.direction_camera.y(), a.direction_camera.z(), a.point_camera.x(),
                  a.point_camera.y(), a.point_camera.z(), r->rms_px);
      for (size_t i = 0; i < r->used.size(); ++i)
        std::printf("  %-20s commanded %8.3f  measured %8.3f  error %+.3f deg\n", r->used[i].c_str(),
                    r->commanded_deg[i], a.step_angles_deg[i], a.step_angles_deg[i] - r->commanded_deg[i]);
      c.axis = a;
      if (auto st = save_calibration(b->out, c); !st) return error(st.error().message);
      return finish(r->report, b->report.empty() ? fs::path(b->out).parent_path() / "report.json" : fs::path(b->report));
    });
  });
  add_calibrate_markers(cal);
}

void add_calibrate_markers(CLI::App* cal) {
  auto* mk = cal->add_subcommand("markers",
                                 "Turntable axis and every frame's table angle from white dot markers on a dark turntable, seen\n"
                                 "by a fixed RGB-D camera (depth aligned to colour): dots (OpenCV), table plane (PCL RANSAC),\n"
                                 "dot matches between frames, one joint fit of the centre and the angles (Ceres). The angles are\n"
                                 "tied to the session: s2r register SESSION --calibration OUT starts from them.");
  struct Args {
    std::string session, out, report;
    MarkerOptions o;
  };
  auto a = std::make_shared<Args>();
  mk->add_option("session", a->session, "session of the object on the marked turntable")->required();
  mk->add_option("--out", a->out, "calibration file to write")->required();
  mk->add_option("--match-tolerance", a->o.match_tolerance_m, "dots closer than this (m) after a motion coincide")->capture_default_str();
  mk->add_option("--min-matches", a->o.min_matches, "dots two frames must share to link them")->capture_default_str();
  mk->add_option("--report", a->report, "report path (default: beside --out)");
  mk->callback([a] {
    set_runner([a] {
      auto r = run_markers_job(a->session, a->out, a->o);
      if (!r) return error(r.error().message);
      return finish(*r, a->report.empty() ? fs::path(a->out).parent_path() / "report.json" : fs::path(a->report));
    });
  });
}

void add_devices(CLI::App& app) {
  auto* sub = app.add_subcommand("devices", "List cameras (V4L2 nodes, libcamera), depth nodes and serial ports");
  sub->callback([] {
    set_runner([] {
      for (const auto& l : list_capture_devices()) std::printf("%s\n", l.c_str());
      return 0;
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
  add_devices(app);
  add_capture(app);
  add_calibrate(app);
}

}  // namespace s2r::cli
