// What each subcommand's flags bind to. The front (`s2r`, app/front.cpp)
// parses into these and hands the command to the engine (`s2r-engine`,
// app/engine.cpp), which parses the same way and runs it (app/run.h).
// Flags bind straight to the libraries' option structs where there is one, so
// each default is written once; a field here is only text the run parses.
// Only headers that declare options belong here: the front links none of the
// stage libraries.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "calibrate/intrinsics.h"
#include "calibrate/table_markers.h"
#include "capture/capture_devices.h"
#include "capture/import_datasets.h"
#include "capture/synth_rig.h"
#include "reconstruct/reconstruct_job.h"
#include "reconstruct/register_job.h"
#include "reconstruct/gltf_export.h"
#include "reconstruct/session_export.h"
#include "render/envmap.h"
#include "render/model_eval.h"
#include "render/raytrace_job.h"
#include "render/session_preview.h"
#include "render/viewer.h"
#include "render/web_export.h"

namespace s2r::cli {

// ---- make and transform data (app/cmd_data.cpp) ----
struct SynthArgs {
  SynthOptions options;
  std::string out, report;
};
struct ImportArgs {
  std::string kind, path, out, report, background;
  ImportOptions options;
};
struct InspectArgs {
  std::string session;
  bool decode = false;
};
struct DevicesArgs {};
// s2r turntable: talk to a GRBL turntable by hand (or to the simulated one).
struct TurntableArgs {
  std::string port, protocol = "grbl";
  bool sim = false, home = false, unlock = false, status = false, serve = false;
  int baud = 115200, turn = 0, steps_per_turn = 3200;
  std::vector<double> moves;
  std::string transcript;
};
struct CaptureArgs {
  CaptureOptions capture;
  DeviceOptions devices;
  SimOptions sim;
  bool use_sim = false, sim_camera = false;
  std::string replay, camera, depth, turntable, report, protocol = "grbl";
  int settle_ms = int(DeviceOptions{}.settle.count());
  int flush = -1;  // -1: the capture's default for real devices, 0 simulated or replayed
  std::vector<std::string> faults;
};
struct IntrinsicsArgs {
  IntrinsicsOptions options;  // the board is parsed from `board`
  std::string images, board, out, report;
};
struct DepthCalibrationArgs {
  std::string session, board = "chessboard:9x6:0.02", out;
};
struct AxisArgs {
  std::string session, board = "chessboard:9x6:0.02", out, intrinsics, report;
};
struct MarkersArgs {
  std::string session, out, report;
  MarkerOptions options;
};

// ---- the reconstruct stage (app/cmd_reconstruct.cpp) ----
struct RegisterArgs {
  RegisterJob job;
  std::string mode = "free", perturb, voxels;
};
struct ReconstructArgs {
  ReconstructJob job;
  std::string voxel = "auto", geometry = std::string(geometry_name(job.geometry)), holdout;
};

// ---- drawing (app/cmd_render.cpp) ----
// The drawing options every model command shares; only the two options that
// need parsing are held as text.
struct DrawArgs {
  DrawOptions d;
  std::string geometry = "auto";  // fitted where the model has a fit, else billboards
  std::string fitted_pass = "auto";
  std::string gaze;  // "" off, "centre", or X,Y pixels
};
// Backdrop, glossy floor and props around a model (render, view).
struct EnvArgs {
  std::string panorama, envmap, floor_map, floor_relief, up = "z";
  double floor = -1, floor_glossy = 0.5;
  std::vector<std::string> spheres;
  int envmap_size = 128;
  bool clamp = false;
};
struct PreviewArgs {
  std::string session, out, report;
  PreviewOptions options;
};
struct RenderArgs {
  RenderJob job;
  std::string report, background;
  int view = -1;  // -1: none (then a view file)
  DrawArgs draw;
  EnvArgs env;
};
struct EvalArgs {
  EvalJob job;
  std::string out, holdout, background;  // out: default MODEL/eval
  DrawArgs draw;
};
struct ViewArgs {
  ViewerOptions options;
  DrawArgs draw;
  EnvArgs env;
};
struct RaytraceArgs {
  RaytraceJob job;
  std::string eye, gaze, out;
  bool full = false, no_compare = false;
};
struct EnvmapArgs {
  EnvmapJob job;
  std::string report;
};

// ---- benches and the run page (app/cmd_bench.cpp, app/cmd_summary.cpp) ----
// bench views' fits: seconds (0: no fitted billboards) and the loss
// (reconstruct --fit-ssim, --fit-loss; the same defaults).
struct ViewsFit {
  double lego = 1500, others = 300;
  double ssim = 0.2;
  std::string loss = "l1";
};
struct BenchArgs {
  std::string stage, out, scene = "blob";
  int repeats = 3, size = 512, voxels = 10000;
  int lego_views = 100;  // views: how many of lego's 100 val views (evenly spaced)
  ViewsFit fit;                               // views: the fits' seconds and loss
  std::vector<std::string> scenes;           // views: the scenes to run (empty: all)
};
struct SummaryArgs {
  std::string folder, title = "scan2render run";
};
// s2r export FORMAT SESSION: a capture for other tools.
struct ExportArgs {
  std::string format, input;
  ExportJob job;       // colmap, nerfstudio: input is a session
  GltfExportJob gltf;  // gltf: input is a model
  WebExportJob web;    // web: input is a model
  std::string background, report;
};
// s2r batch (app/batch.h): many captures through the same steps.
struct BatchArgs {
  std::string root, out, steps = "import,calibrate,register,reconstruct,eval", options, status;
  int jobs = 1;
  bool retry_failed = false;
  int task = -1, tasks = 0;  // a Slurm array task (the script --slurm writes runs it)
  bool slurm = false;
  std::string partition, time, sbatch = "sbatch";
  double mem_mb = 0;
  int cpus_per_task = 2;
  std::vector<std::string> sbatch_args;
};

// The command a parse chose, with its arguments. Every subcommand's type is
// listed here once: the engine runs each through `run(const A&)` (app/run.h),
// so a command without a runner does not link.
using Chosen =
    std::variant<std::monostate, std::shared_ptr<SynthArgs>, std::shared_ptr<ImportArgs>, std::shared_ptr<InspectArgs>,
                 std::shared_ptr<DevicesArgs>, std::shared_ptr<TurntableArgs>, std::shared_ptr<CaptureArgs>, std::shared_ptr<IntrinsicsArgs>,
                 std::shared_ptr<DepthCalibrationArgs>, std::shared_ptr<AxisArgs>, std::shared_ptr<MarkersArgs>,
                 std::shared_ptr<RegisterArgs>, std::shared_ptr<ReconstructArgs>, std::shared_ptr<PreviewArgs>,
                 std::shared_ptr<RenderArgs>, std::shared_ptr<EvalArgs>, std::shared_ptr<ViewArgs>,
                 std::shared_ptr<RaytraceArgs>, std::shared_ptr<EnvmapArgs>, std::shared_ptr<BenchArgs>,
                 std::shared_ptr<SummaryArgs>, std::shared_ptr<BatchArgs>, std::shared_ptr<ExportArgs>>;

}  // namespace s2r::cli
