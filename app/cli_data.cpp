// Flags of the subcommands that make or transform data: synth, import,
// inspect, devices, capture, calibrate (run by app/cmd_data.cpp).
#include "app/cli.h"

namespace s2r::cli {

namespace {

void add_synth(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("synth", "Synthetic turntable rig with ground truth (session + ground_truth/)");
  auto a = std::make_shared<SynthArgs>();
  SynthOptions& o = a->options;
  sub->add_option("--scene", o.scene, "bunny | fuzzy | room | blob")->capture_default_str();
  sub->add_option("--views", o.views, "turntable steps over 360 degrees")->capture_default_str();
  sub->add_option("--seed", o.seed, "noise seed (same seed, same bytes)")->capture_default_str();
  sub->add_option("--out", a->out, "session folder to create")->required();
  sub->add_option("--width", o.width, "image width (intrinsics scale with it)")->capture_default_str();
  sub->add_option("--height", o.height, "image height")->capture_default_str();
  sub->add_option("--spp", o.spp, "colour samples per pixel (1 or 4)")->capture_default_str();
  sub->add_option("--depth-noise", o.depth_noise_k, "depth sigma = k z^2 (m)")->capture_default_str();
  sub->add_option("--exposure", o.exposure, "colour gain (clips above 1)")->capture_default_str();
  sub->add_option("--color-noise", o.color_noise, "colour noise sigma, 8-bit levels")->capture_default_str();
  sub->add_option("--dropout", o.dropout, "random depth hole probability")->capture_default_str();
  sub->add_option("--grazing-deg", o.grazing_deg, "no depth beyond this incidence angle")->capture_default_str();
  sub->add_option("--table-error-deg", o.table_error_deg, "table turns this much less per step")->capture_default_str();
  sub->add_option("--threads", o.threads, "0 = all cores")->capture_default_str();
  sub->add_option("--data", o.data_dir, "real data folder (default $S2R_DATA or ../shared/data)");
  sub->add_option("--report", a->report, "report path (default OUT/report.json)");
  sub->callback([a, &chosen] { chosen = a; });
}

void add_import(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("import", "Turn a real data set into a session");
  auto a = std::make_shared<ImportArgs>();
  sub->add_option("kind", a->kind, "stanford | middlebury | realsense | 7scenes | nerf | colmap")
      ->required()->check(CLI::IsMember({"stanford", "middlebury", "realsense", "7scenes", "nerf", "colmap"}));
  sub->add_option("path", a->path, "stanford: the .conf; nerf: the folder or its transforms JSON; colmap: the model folder "
                  "(or a project with sparse/0); others: the data folder")
      ->required();
  sub->add_option("--out", a->out, "session folder to create")->required();
  sub->add_option("--stride", a->options.stride, "take every n-th view")->capture_default_str();
  sub->add_option("--max-frames", a->options.max_frames, "0 = all")->capture_default_str();
  sub->add_option("--split", a->options.split, "nerf: transforms_SPLIT.json (train, val, test); default transforms.json, "
                  "else the train split");
  sub->add_option("--images", a->options.images, "colmap: the images' folder (default PATH/images, else beside the model)");
  sub->add_option("--background", a->background, "nerf: white, black or R,G,B (0-255 levels) under RGBA photos; default white");
  sub->add_option("--report", a->report, "report path (default OUT/report.json)");
  sub->callback([a, &chosen] { chosen = a; });
}

void add_capture(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("capture", "Run a turntable capture session (simulated, replayed or real devices)");
  auto a = std::make_shared<CaptureArgs>();
  sub->add_option("--out", a->capture.out, "session folder")->required();
  sub->add_option("--steps", a->capture.steps, "turntable steps over 360 degrees")->capture_default_str();
  sub->add_flag("--resume", a->capture.resume, "continue a session that was interrupted or killed");
  auto* sim = sub->add_flag("--sim", a->use_sim, "simulated rig: real V4L2/GRBL driver code over simulated devices");
  auto* rep = sub->add_option("--replay", a->replay, "replay a recording folder (color.v4l2rec, depth.v4l2rec, turntable.transcript)");
  auto* cam = sub->add_option("--camera", a->camera, "colour camera: /dev/videoN or libcamera:ID");
  sub->add_option("--depth", a->depth, "depth camera node (UVC Z16), optional");
  auto* tty = sub->add_option("--turntable", a->turntable, "serial port of the turntable, e.g. /dev/ttyUSB0");
  sub->add_option("--protocol", a->protocol, "--turntable's firmware: grbl, horus or fabscan")
      ->capture_default_str()->check(CLI::IsMember({"grbl", "horus", "fabscan"}));
  auto* simcam = sub->add_flag("--sim-camera", a->sim_camera,
                               "with --turntable: the simulated colour and depth cameras, drawing --scene at the angle "
                               "the real table reports (check a table before a camera is bought)");
  sim->excludes(rep)->excludes(cam)->excludes(simcam);
  rep->excludes(cam)->excludes(simcam);
  cam->needs(tty);
  cam->excludes(simcam);
  simcam->needs(tty);
  sub->add_option("--record", a->devices.record_dir, "also record the device boundaries into this folder");
  sub->add_option("--width", a->devices.width, "image width")->capture_default_str();
  sub->add_option("--height", a->devices.height, "image height")->capture_default_str();
  sub->add_option("--settle-ms", a->settle_ms, "wait after the table stops")->capture_default_str();
  sub->add_option("--flush", a->flush, "colour frames dropped after each move (default: 2 real, 0 sim/replay)");
  sub->add_option("--scene", a->sim.scene, "--sim: rig scene (bunny, fuzzy, room, blob)")->capture_default_str();
  sub->add_option("--seed", a->sim.seed, "--sim: noise seed")->capture_default_str();
  sub->add_option("--sim-fault", a->faults, "--sim: inject KIND@N (camera-vanish, depth-vanish, camera-timeout, "
                                            "eagain-storm, serial-silent, table-alarm, drop-ok, table-reset)");
  sub->add_option("--report", a->report, "report path (default OUT/report.json)");
  sub->callback([a, &chosen] { chosen = a; });
}

void add_calibrate_markers(CLI::App* cal, Chosen& chosen) {
  auto* mk = cal->add_subcommand("markers",
                                 "Turntable axis and every frame's table angle from white dot markers on a dark turntable, seen\n"
                                 "by a fixed RGB-D camera (depth aligned to colour): dots (OpenCV), table plane (PCL RANSAC),\n"
                                 "dot matches between frames, one joint fit of the centre and the angles (Ceres). The angles are\n"
                                 "tied to the session: s2r register SESSION --calibration OUT starts from them.");
  auto a = std::make_shared<MarkersArgs>();
  mk->add_option("session", a->session, "session of the object on the marked turntable")->required();
  mk->add_option("--out", a->out, "calibration file to write")->required();
  mk->add_option("--match-tolerance", a->options.match_tolerance_m, "dots closer than this (m) after a motion coincide")->capture_default_str();
  mk->add_option("--min-matches", a->options.min_matches, "dots two frames must share to link them")->capture_default_str();
  mk->add_option("--report", a->report, "report path (default: beside --out)");
  mk->callback([a, &chosen] { chosen = a; });
}

void add_calibrate(CLI::App& app, Chosen& chosen) {
  auto* cal = app.add_subcommand("calibrate", "Camera intrinsics, depth-to-colour, turntable axis");
  cal->require_subcommand(1);
  auto* in = cal->add_subcommand("intrinsics", "Intrinsics from chessboard or ChArUco photos (OpenCV)");
  auto a = std::make_shared<IntrinsicsArgs>();
  in->add_option("--images", a->images, "glob of board photos, e.g. 'calib/*.jpg'")->required();
  in->add_option("--board", a->board, "chessboard:COLSxROWS:SQUARE_M or charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]")
      ->required();
  in->add_option("--out", a->out, "calibration file to write (JSON, s2r.calibration)")->required();
  in->add_option("--reject-factor", a->options.reject_factor, "drop a view whose RMS exceeds this x the median")
      ->capture_default_str();
  in->add_flag("--fix-k3", a->options.fix_k3, "keep k3 = 0 (most lenses; steadier with few or central views)");
  in->add_option("--report", a->report, "report path (default: beside --out)");
  in->callback([a, &chosen] { chosen = a; });

  auto* dc = cal->add_subcommand("depth", "Depth-to-colour extrinsic from a board seen by both cameras");
  auto d = std::make_shared<DepthCalibrationArgs>();
  dc->add_option("session", d->session, "session with colour and depth frames of a board")->required();
  dc->add_option("--board", d->board, "board spec")->capture_default_str();
  dc->add_option("--out", d->out, "calibration file to write (the extrinsic is added)")->required();
  dc->callback([d, &chosen] { chosen = d; });

  auto* ax = cal->add_subcommand("axis", "Turntable axis from board views at known table angles (Ceres)");
  auto b = std::make_shared<AxisArgs>();
  ax->add_option("session", b->session, "session whose frames show a board standing on the table")->required();
  ax->add_option("--board", b->board, "board spec")->capture_default_str();
  ax->add_option("--out", b->out, "calibration file to write (the axis is added to what it holds)")->required();
  ax->add_option("--intrinsics", b->intrinsics, "calibration file with the colour intrinsics (default: the session's)");
  ax->add_option("--report", b->report, "report path (default: beside --out)");
  ax->callback([b, &chosen] { chosen = b; });
  add_calibrate_markers(cal, chosen);
}

void add_devices(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("devices", "List cameras (V4L2 nodes, libcamera), depth nodes and serial ports");
  sub->callback([&chosen] { chosen = std::make_shared<DevicesArgs>(); });
}

void add_turntable(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("turntable",
                                 "Talk to a turntable by hand before a capture: its banner and state, then homing, "
                                 "moves and a full turn in order (GRBL 1.1, Horus or FabScanPi firmware)");
  auto a = std::make_shared<TurntableArgs>();
  auto* port = sub->add_option("port", a->port, "serial port (e.g. /dev/ttyUSB0)");
  auto* sim = sub->add_flag("--sim", a->sim, "the simulated firmware of --protocol on a pseudo-terminal instead of a port");
  port->excludes(sim);
  sub->add_option("--protocol", a->protocol, "the board's firmware: grbl (GRBL 1.1), horus (Ciclop/Horus, GRBL 0.9), "
                                             "fabscan (FabScanPi)")
      ->capture_default_str()->check(CLI::IsMember({"grbl", "horus", "fabscan"}));
  sub->add_option("--baud", a->baud, "baud rate")->capture_default_str()->check(CLI::PositiveNumber);
  sub->add_flag("--status", a->status, "print the board's state and the table's angle, and nothing else");
  sub->add_flag("--home", a->home, "take the current angle as 0 first (grbl: G92 X0, horus: G50, fabscan: the count)");
  sub->add_flag("--unlock", a->unlock, "grbl, horus: unlock a board that starts in Alarm ($X)");
  sub->add_option("--move", a->moves, "move to this angle (degrees; repeat for several)")->take_all();
  sub->add_option("--turn", a->turn, "then a full turn in N steps of 360/N deg, each step's reported angle and "
                                     "seconds")->check(CLI::Range(1, 100000));
  sub->add_option("--steps-per-turn", a->steps_per_turn, "fabscan: motor steps a full turn of the table")
      ->capture_default_str()->check(CLI::PositiveNumber);
  sub->add_option("--transcript", a->transcript, "append every line both ways to this file");
  sub->add_flag("--serve", a->serve, "with --sim: print the simulated board's port and keep it running until Ctrl-C, "
                                     "for another program (s2r capture --turntable PORT) to talk to")
      ->needs(sim);
  sub->callback([a, &chosen] {
    if (a->port.empty() && !a->sim) throw CLI::ValidationError("turntable", "give a serial port or --sim");
    chosen = a;
  });
}

void add_inspect(CLI::App& app, Chosen& chosen) {
  auto* sub = app.add_subcommand("inspect", "Validate a session and print a summary");
  auto a = std::make_shared<InspectArgs>();
  sub->add_option("session", a->session, "session folder")->required();
  sub->add_flag("--decode", a->decode, "also decode every image (finds truncated files)");
  sub->callback([a, &chosen] { chosen = a; });
}

}  // namespace

void add_data_commands(CLI::App& app, Chosen& chosen) {
  add_synth(app, chosen);
  add_import(app, chosen);
  add_inspect(app, chosen);
  add_devices(app, chosen);
  add_turntable(app, chosen);
  add_capture(app, chosen);
  add_calibrate(app, chosen);
}

}  // namespace s2r::cli
