// Runs the reconstruct stage's subcommands: register, reconstruct (their
// flags: app/cli_reconstruct.cpp).
#include <cmath>
#include <optional>
#include <sstream>

#include "app/run.h"
#include "reconstruct/reconstruct_job.h"
#include "reconstruct/register_job.h"
#include "reconstruct/session_export.h"
#include "render/web_export.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {

// "5,0.005" -> (5, 0.005)
std::optional<std::pair<double, double>> parse_pair(const std::string& s) {
  std::istringstream in(s);
  double a = 0, b = 0;
  char comma = 0;
  if (!(in >> a >> comma >> b) || comma != ',' || !in.eof() || !std::isfinite(a) || !std::isfinite(b) || a < 0 ||
      b < 0)
    return std::nullopt;
  return std::make_pair(a, b);
}

}  // namespace

int run(const RegisterArgs& a) {
  static const FlagNames flags = {{"session", "session"},        {"stanford_conf", "--stanford"},
                                  {"out", "--out"},              {"table_sigma_deg", "--table-sigma-deg"},
                                  {"threads", "--threads"},      {"voxel_m", "--voxels"},
                                  {"perturb", "--perturb"},      {"fixed_name", "--fixed"},
                                  {"mode", "--mode"}};
  RegisterJob job = a.job;
  job.options.mode = a.mode == "turntable" ? RegistrationMode::kTurntable : RegistrationMode::kFree;
  if (!a.perturb.empty()) {
    auto p = parse_pair(a.perturb);
    if (!p) return error("--perturb expects DEG,M with two non-negative numbers, e.g. 5,0.005");
    job.perturb_deg = p->first;
    job.perturb_m = p->second;
  }
  for (const auto& item : comma_items(a.voxels)) {
    const auto v = positive_metres(item);
    if (!v) return error("--voxels: '" + item + "' is not a positive length in metres");
    job.options.voxel_m.push_back(*v);
  }
  auto r = run_register_job(job);
  if (!r) return error(in_flag_terms(r.error(), flags));
  return finish(r->to_report(), job.out / "report.json");
}

int run(const ReconstructArgs& a) {
  static const FlagNames flags = {{"target_error_px", "--target-error"}, {"truncation_voxels", "--truncation"},
                                  {"voxel_m", "--voxel"}, {"threads", "--threads"}, {"geometry", "--geometry"},
                                  {"holdout", "--holdout"}};
  ReconstructJob job = a.job;
  job.geometry = *parse_geometry(a.geometry);  // CLI11 checked the name
  if (a.voxel != "auto") {
    job.voxel_m = positive_metres(a.voxel);
    if (!job.voxel_m) return error("--voxel: '" + a.voxel + "' is neither 'auto' nor a positive length in metres");
  }
  auto held = frame_list(a.holdout, "--holdout");
  if (!held) return error(held.error().message);
  job.holdout = *held;
  auto r = run_reconstruct_job(job);
  if (!r) return error(in_flag_terms(r.error(), flags));
  return finish(r->to_report(), job.out / "report.json");
}

int run(const ExportArgs& a) {
  static const FlagNames flags = {{"max_points", "--max-points"}, {"out", "--out"},     {"format", "format"},
                                  {"atlas_max", "--atlas"},       {"max_cell", "--cell"}, {"mesh", "--mesh"},
                                  {"budget_mib", "--budget-mib"}};
  Result<Report> r;
  fs::path report = a.report;
  if (a.format == "web") {
    WebExportJob job = a.web;
    job.model = a.input;
    job.out = a.job.out;
    if (!a.background.empty()) {
      auto bg = parse_background(a.background, "--background");
      if (!bg) return error(bg.error().message);
      job.background = *bg;
    }
    r = export_web(job);
    if (report.empty()) {
      if (!r) return error(in_flag_terms(r.error(), flags));
      std::printf("%s\nreport: %s\nopen: %s (served by any static server, e.g. python3 -m http.server -d %s)\n",
                  r->brief().c_str(), (job.out / "report.json").c_str(), (job.out / "index.html").c_str(), job.out.c_str());
      return 0;
    }
  } else if (a.format == "gltf") {
    GltfExportJob job = a.gltf;
    job.model = a.input;
    job.out = a.job.out;
    r = export_gltf(job);
    if (report.empty()) report = job.out.parent_path() / (job.out.stem().string() + ".report.json");
  } else {
    ExportJob job = a.job;
    job.format = a.format;
    job.session = a.input;
    r = export_session(job);
    if (report.empty()) {
      if (!r) return error(in_flag_terms(r.error(), flags));
      std::printf("%s\nreport: %s\n", r->brief().c_str(), (job.out / "report.json").c_str());
      return 0;
    }
  }
  if (!r) return error(in_flag_terms(r.error(), flags));
  return finish(*r, report);
}

}  // namespace s2r::cli
