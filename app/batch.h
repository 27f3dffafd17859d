// s2r batch: many captures through the same steps, on this machine or as a
// Slurm job array. Every step is one `s2r` subcommand run as its own process
// (a crash in one capture never takes the others down), writing into
// RESULTS/<capture>/; what finished is read back from files only:
//
//   RESULTS/batch.json                 the plan: root, captures, steps, options
//   RESULTS/<capture>/<step>/          the step's outputs (session/, calibrate/,
//                                      register/, model/, eval/, export/)
//   RESULTS/<capture>/steps/<step>.json  written after the step exited 0: its
//                                      command, seconds, peak memory
//   RESULTS/<capture>/logs/<step>.log  the step's stdout and stderr
//   RESULTS/<capture>/status.json      running | done | failed (step, log tail)
//   RESULTS/index.html, summary.json   one row per capture, failures first
//
// A step whose record matches its command and whose outputs exist and
// validate is skipped (said so); a step without a record is run again from an
// empty output folder, so a killed batch resumes where it stopped. This is
// COLMAP's controller's rule, with no database: the files are the state.
#pragma once

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/result.h"

namespace s2r::batch {

// The steps, in the order they run.
inline const std::vector<std::string>& all_steps() {
  static const std::vector<std::string> s = {"import", "calibrate", "register", "reconstruct", "eval", "export"};
  return s;
}
// "import,reconstruct" -> those steps in pipeline order; unknown or repeated
// names are an error naming the choices.
Result<std::vector<std::string>> parse_steps(const std::string& csv);

// The options file (JSON), the same for every capture:
//   {"holdout": "auto" | "none" | "3,7",   frames held out of a session's fit
//    "heldout_views": 10,                  views of a separate held-out split evaluated
//    "export": "nerfstudio" | "colmap" | "gltf",  what the export step writes
//    "import": [..], "calibrate": [..], "register": [..], "reconstruct": [..],
//    "eval": [..], "export_args": [..]}     extra arguments of each step's subcommand
struct Options {
  std::string holdout = "auto";
  int heldout_views = 10;
  std::string export_format = "nerfstudio";
  std::map<std::string, std::vector<std::string>> extra;  // step -> arguments
  std::string text;                                       // the file as read ("{}" without one)
};
Result<Options> parse_options(const std::string& json_text, const std::string& name);
Result<Options> load_options(const std::filesystem::path& file);  // empty path: the defaults

// A capture found under the root: a session folder (session.json) or a data
// set with an importer: nerf (transforms.json / transforms_train.json),
// colmap (cameras.txt|bin, or sparse/0/), middlebury (*_par.txt), realsense
// (color/color_0.png + depth/depth_0.png), 7scenes (frame-000000.color.* +
// .pose.txt). Stanford range scans are left out: they have no colour to
// reconstruct from (s2r register --stanford takes them).
struct Capture {
  std::string name;  // RESULTS/<name>: the path under the root, '/' -> '_'
  std::filesystem::path path;
  std::string kind;  // session | nerf | colmap | middlebury | realsense | 7scenes
};
std::optional<std::string> capture_kind(const std::filesystem::path& dir);
// The root itself if it is a capture, else every capture below it (three
// levels at most, not below a capture), sorted by name. None found is an error.
Result<std::vector<Capture>> discover(const std::filesystem::path& root);

// What a step does for one capture. `needed` false: nothing to run, `reason`
// says why (a session needs no import; given poses need no calibration).
struct StepPlan {
  std::string step;
  bool needed = true;
  std::string reason;
  std::vector<std::vector<std::string>> commands;  // each after "s2r", run in order
  std::vector<std::string> outputs;  // folders under the capture's results, emptied before a run
};

// What the steps before this one left, read from the results folder.
struct CaptureState {
  std::filesystem::path session;  // the session the later steps read
  std::filesystem::path heldout;  // a separate held-out split (nerf val), or empty
  bool has_poses = false;         // the session's frames carry poses
  bool has_depth = false;
  int frames = 0, heldout_frames = 0;
  bool calibrated = false, registered = false;
  // The calibration measured every frame's table angle from the session's
  // own images (calibrate markers): the model is built on those poses and
  // registration only checks them (on a round table its turns slide about
  // the axis: docs/cli.md, the bench's bear row).
  bool table_poses = false;
};
// `dir` is RESULTS/<capture>. The session's facts are read from its files
// (an error when the session cannot be loaded).
Result<CaptureState> capture_state(const Capture& c, const std::filesystem::path& dir);
Result<StepPlan> plan_step(const std::string& step, const Capture& c, const std::filesystem::path& dir,
                           const CaptureState& state, const Options& options);
// "auto": one frame in 8 from frame 3 (at least one, never all); "none"; a list.
Result<std::vector<int>> holdout_frames(const std::string& spec, int frames);

// What a finished step wrote (RESULTS/<capture>/steps/<step>.json).
struct StepRecord {
  std::string step;
  std::vector<std::vector<std::string>> commands;
  double seconds = 0;
  double peak_mb = 0;
  std::string finished;  // UTC, ISO 8601
  std::string host;
};
Status write_record(const std::filesystem::path& dir, const StepRecord& r);
Result<StepRecord> read_record(const std::filesystem::path& dir, const std::string& step);
// Empty: the step's record matches `plan` and its outputs exist and validate
// (the session loads; report.json parses and names its stage; the step's main
// file parses). Else why it must run.
std::string why_rerun(const std::filesystem::path& dir, const StepPlan& plan);

// One process: its exit code (128 + signal when killed), seconds and peak
// resident memory; stdout and stderr go to `log` (after the command line),
// appended to it or replacing it.
struct ProcessResult {
  int code = -1;
  double seconds = 0, peak_mb = 0;
};
Result<ProcessResult> run_process(const std::filesystem::path& program, const std::vector<std::string>& args,
                                  const std::filesystem::path& log, bool append);
std::string log_tail(const std::filesystem::path& log, int lines);

// The batch as a whole.
struct Manifest {
  std::filesystem::path root;
  std::vector<Capture> captures;
  std::vector<std::string> steps;
  Options options;
};
Status write_manifest(const std::filesystem::path& results, const Manifest& m);
Result<Manifest> read_manifest(const std::filesystem::path& results);

struct RunOptions {
  std::filesystem::path s2r;  // the program every step runs
  int jobs = 1;
  bool retry_failed = false;
  bool quiet = false;
};
// Runs captures `indices` of the manifest (each through every step in order).
// Returns how many failed.
int run_captures(const std::filesystem::path& results, const Manifest& m, const std::vector<int>& indices,
                 const RunOptions& o);

// RESULTS/status: one row per capture, read from the files.
struct Row {
  std::string name, kind, state;  // done | failed | running | pending
  std::string failed_step, message, log;
  double seconds = 0, peak_mb = 0;
  std::map<std::string, double> psnr;  // method -> full-image held-out PSNR
  std::vector<std::string> warnings, skipped_steps;
};
std::vector<Row> collect(const std::filesystem::path& results, const Manifest& m);
// RESULTS/index.html and RESULTS/summary.json, atomically; failures first.
Status write_summary(const std::filesystem::path& results, const Manifest& m, const std::vector<Row>& rows);

// Slurm: a job array (one task per capture, or per several when there are
// more than `max_array` captures) and a summary job after it (afterany).
struct SlurmOptions {
  int cpus_per_task = 2;
  double mem_mb = 0;       // 0: from the steps' measured peaks
  std::string time = "";   // sbatch --time; empty: from the steps' measured seconds
  std::string partition;
  std::vector<std::string> sbatch_args;  // passed through to both submissions
  int max_array = 1000;
  std::filesystem::path sbatch = "sbatch";
};
// The memory a task asks for: the largest peak any step of any capture
// reached in RESULTS (times 1.5, plus 512 MB), else the defaults measured
// on the bundled data (docs/cli.md); and the time limit likewise.
double task_memory_mb(const std::filesystem::path& results, const std::vector<std::string>& steps);
std::string task_time(const std::filesystem::path& results, const std::vector<std::string>& steps, int captures_per_task);
struct Submission {
  std::string array_job, summary_job;
  int tasks = 0;
  double mem_mb = 0;
  std::string time;
};
Result<Submission> submit_slurm(const std::filesystem::path& results, const Manifest& m,
                                const std::filesystem::path& s2r, const SlurmOptions& o);
// The captures array task `task` of `tasks` runs.
std::vector<int> task_captures(int task, int tasks, int captures);

}  // namespace s2r::batch
