// Runs the subcommands that make or transform data: synth, import, inspect,
// devices, capture, calibrate (their flags: app/cli_data.cpp).
#include <chrono>
#include <thread>
#include <cstdio>
#include <csignal>

#include <glob.h>

#include "app/run.h"
#include "calibrate/depth_to_color.h"
#include "calibrate/intrinsics.h"
#include "calibrate/table_markers.h"
#include "calibrate/turntable_axis.h"
#include "capture/capture_devices.h"
#include "capture/capture_session.h"
#include "capture/grbl_sim.h"
#include "capture/grbl_turntable.h"
#include "capture/import_datasets.h"
#include "capture/session.h"
#include "capture/synth_rig.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {

// REPORT, or DEFAULT when the flag was not given.
fs::path report_path(const std::string& report, const fs::path& fallback) {
  return report.empty() ? fallback : fs::path(report);
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

}  // namespace

int run(const SynthArgs& a) {
  static const FlagNames flags = {{"views", "--views"}, {"width", "--width"}, {"height", "--height"}, {"spp", "--spp"},
                                  {"depth_noise_k", "--depth-noise"}, {"dropout", "--dropout"},
                                  {"grazing_deg", "--grazing-deg"}, {"exposure", "--exposure"},
                                  {"color_noise", "--color-noise"}};
  auto r = synth_session(a.options, a.out);
  if (!r) return error(in_flag_terms(r.error(), flags));
  return finish(*r, report_path(a.report, fs::path(a.out) / "report.json"));
}

int run(const ImportArgs& a) {
  ImportOptions o = a.options;
  if (!a.background.empty()) {
    auto bg = parse_background(a.background, "--background");
    if (!bg) return error(bg.error().message);
    o.background = *bg;
  }
  auto r = import_dataset(a.kind, a.path, a.out, o);
  if (!r) return error(r.error().message);
  return finish(*r, report_path(a.report, fs::path(a.out) / "report.json"));
}

int run(const CaptureArgs& a) {
  if (!a.use_sim && a.replay.empty() && a.camera.empty() && !a.sim_camera)
    return error("choose the devices: --sim, --replay DIR, --camera DEV --turntable TTY, or --turntable TTY --sim-camera");
  // From here on SIGINT/SIGTERM end the session cleanly between frames.
  struct sigaction sa {};
  sa.sa_handler = on_stop_signal;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  DeviceOptions d = a.devices;
  d.settle = std::chrono::milliseconds(a.settle_ms);
  Result<std::unique_ptr<CaptureRig>> rig = fail("no devices");
  if (a.use_sim) {
    SimOptions so = a.sim;
    for (const auto& f : a.faults)
      if (auto st = apply_sim_fault(f, so); !st) return error(st.error().message);
    rig = make_sim_capture(so, d);
  } else if (!a.replay.empty()) {
    rig = make_replay_capture(a.replay, d);
  } else if (a.sim_camera) {
    rig = make_sim_camera_capture(a.turntable, a.protocol, a.sim, d);
  } else {
    rig = make_hardware_capture(a.camera, a.depth, a.turntable, d, a.protocol);
  }
  if (!rig) return error(rig.error().message);
  CaptureOptions o = a.capture;
  if (a.flush >= 0) o.flush_frames = a.flush;
  else if (a.use_sim || !a.replay.empty() || a.sim_camera) o.flush_frames = 0;
  auto r = run_capture((*rig)->devices, o, &g_stop);
  if (!r) {
    std::fprintf(stderr, "s2r: error: %s\n", in_flag_terms(r.error(), {{"steps", "--steps"}}).c_str());
    if (fs::exists(o.out / "session.json"))
      std::fprintf(stderr, "s2r: the session keeps every complete frame; continue with: s2r capture --out %s --resume ...\n",
                   o.out.c_str());
    return g_stop ? 130 : 1;
  }
  return finish(*r, report_path(a.report, o.out / "report.json"));
}

int run(const IntrinsicsArgs& a) {
  auto board = BoardSpec::parse(a.board);
  if (!board) return error(board.error().message);
  const auto files = expand_glob(a.images);
  if (files.empty()) return error("no file matches '" + a.images + "'");
  IntrinsicsOptions o = a.options;
  o.board = *board;
  auto r = calibrate_intrinsics_from_files(files, o);
  if (!r) return error(r.error().message);
  for (const auto& v : r->views)
    std::printf("%-24s %s %s\n", v.name.c_str(), v.used ? ("rms " + std::to_string(v.rms_px) + " px").c_str() : "not used",
                v.note.c_str());
  const auto& K = r->calibration.intrinsics;
  std::printf("fx %.3f +- %.3f  fy %.3f +- %.3f  cx %.3f +- %.3f  cy %.3f +- %.3f\n", K.fx, r->stddev[0], K.fy,
              r->stddev[1], K.cx, r->stddev[2], K.cy, r->stddev[3]);
  std::printf("dist %.5f %.5f %.5f %.5f %.5f   RMS %.4f px over %d views\n", K.dist[0], K.dist[1], K.dist[2], K.dist[3],
              K.dist[4], r->calibration.rms_px, r->calibration.views);
  Calibration c = existing_calibration(a.out);
  c.color = r->calibration;
  if (auto st = save_calibration(a.out, c); !st) return error(st.error().message);
  return finish(r->report, report_path(a.report, fs::path(a.out).parent_path() / "report.json"));
}

int run(const DepthCalibrationArgs& a) {
  auto board = BoardSpec::parse(a.board);
  if (!board) return error(board.error().message);
  auto s = load_session(a.session);
  if (!s) return error(s.error().message);
  if (!s->color || !s->depth) return error("the session needs a colour and a depth sensor");
  Calibration c = existing_calibration(a.out);
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
  if (auto st = save_calibration(a.out, c); !st) return error(st.error().message);
  return finish(r->report, fs::path(a.out).parent_path() / "report.json");
}

int run(const AxisArgs& b) {
  auto board = BoardSpec::parse(b.board);
  if (!board) return error(board.error().message);
  auto s = load_session(b.session);
  if (!s) return error(s.error().message);
  Calibration c = existing_calibration(b.out);
  std::optional<Intrinsics> K;
  if (!b.intrinsics.empty()) {
    auto ic = load_calibration(b.intrinsics);
    if (!ic) return error(ic.error().message);
    if (!ic->color) return error(b.intrinsics + ": no colour intrinsics in it");
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
  std::printf("axis direction (camera) %.6f %.6f %.6f  point %.5f %.5f %.5f m  RMS %.3f px\n", a.direction_camera.x(),
              a.direction_camera.y(), a.direction_camera.z(), a.point_camera.x(), a.point_camera.y(), a.point_camera.z(),
              r->rms_px);
  for (size_t i = 0; i < r->used.size(); ++i)
    std::printf("  %-20s commanded %8.3f  measured %8.3f  error %+.3f deg\n", r->used[i].c_str(), r->commanded_deg[i],
                a.step_angles_deg[i], a.step_angles_deg[i] - r->commanded_deg[i]);
  c.axis = a;
  if (auto st = save_calibration(b.out, c); !st) return error(st.error().message);
  return finish(r->report, report_path(b.report, fs::path(b.out).parent_path() / "report.json"));
}

int run(const MarkersArgs& a) {
  auto r = run_markers_job(a.session, a.out, a.options);
  if (!r) return error(r.error().message);
  return finish(*r, report_path(a.report, fs::path(a.out).parent_path() / "report.json"));
}

int run(const DevicesArgs&) {
  for (const auto& l : list_capture_devices()) std::printf("%s\n", l.c_str());
  return 0;
}

int run(const TurntableArgs& a) {
  SimBoard board;
  std::string port = a.port;
  if (a.sim) {
    auto b = start_sim_board(a.protocol);
    if (!b) return error(b.error().message);
    board = std::move(*b);
    port = board.port();
  }
  if (a.serve) {
    struct sigaction sa {};
    sa.sa_handler = on_stop_signal;
    sigaction(SIGINT, &sa, nullptr);
    sigaction(SIGTERM, &sa, nullptr);
    std::printf("%s\n", port.c_str());
    std::fflush(stdout);
    std::fprintf(stderr, "turntable: the simulated %s board answers on %s until Ctrl-C\n", a.protocol.c_str(), port.c_str());
    while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    return 0;
  }
  TurntableChoice c;
  c.protocol = a.protocol;
  c.baud = a.baud;
  c.unlock = a.unlock;
  c.steps_per_turn = a.steps_per_turn;
  c.transcript = a.transcript;
  auto t = open_turntable(port, c);
  if (!t) return error(t.error().message);
  Turntable& table = **t;
  std::printf("%s\n", table.describe().c_str());
  if (auto* g = dynamic_cast<GrblTurntable*>(&table)) {
    auto s = g->status();
    if (!s) return error(s.error().message);
    std::printf("state %s, at %.3f deg\n", s->state.c_str(), s->position);
  } else {
    auto p = table.position();
    if (!p) return error(p.error().message);
    std::printf("at %.3f deg (the driver's count: the board reports no position)\n", *p);
  }
  if (a.status) return 0;
  if (a.home) {
    if (auto st = table.home(); !st) return error(st.error().message);
    std::printf("homed: the current angle is 0\n");
  }
  auto move = [&](double deg, const char* what) -> bool {
    const auto t0 = std::chrono::steady_clock::now();
    if (auto st = table.move_to(deg); !st) {
      error(st.error().message);
      return false;
    }
    auto p = table.position();
    if (!p) {
      error(p.error().message);
      return false;
    }
    std::printf("%s %.3f deg (asked %.3f, off %+.3f) in %.2f s\n", what, *p, deg, *p - deg,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    return true;
  };
  for (double deg : a.moves)
    if (!move(deg, "moved to")) return 1;
  if (a.turn > 0) {
    auto start = table.position();
    if (!start) return error(start.error().message);
    std::printf("a full turn in %d steps of %.3f deg from %.3f deg:\n", a.turn, 360.0 / a.turn, *start);
    double worst = 0;
    for (int i = 1; i <= a.turn; ++i) {
      const double target = *start + 360.0 * i / a.turn;
      char what[32];
      std::snprintf(what, sizeof what, "  step %d/%d at", i, a.turn);
      if (!move(target, what)) return 1;
      auto p = table.position();
      if (p) worst = std::max(worst, std::abs(*p - target));
    }
    std::printf("turned 360 deg; largest difference between asked and reported: %.3f deg\n", worst);
  }
  return 0;
}

int run(const InspectArgs& a) {
  auto s = load_session(a.session);
  if (!s) return error(s.error().message);
  std::printf("session %s (%s): %zu frames, layout %s\n", s->name.c_str(), s->source.c_str(), s->frames.size(),
              s->layout == Layout::kObjectCentre ? "object_centre" : "camera_centre");
  if (s->color)
    std::printf("  colour: %s %dx%d fx %.2f fy %.2f\n", s->color->driver.c_str(), s->color->intrinsics.width,
                s->color->intrinsics.height, s->color->intrinsics.fx, s->color->intrinsics.fy);
  if (s->depth) std::printf("  depth: %s unit %.4g m\n", s->depth->driver.c_str(), s->depth->unit_m);
  if (a.decode)
    for (const auto& f : s->frames) {
      if (!f.color.empty())
        if (auto c = load_color(*s, f); !c) return error(c.error().message);
      if (!f.depth.empty())
        if (auto d = load_depth(*s, f); !d) return error(d.error().message);
    }
  std::printf("ok\n");
  return 0;
}

}  // namespace s2r::cli
