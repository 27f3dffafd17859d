// Subcommands of the reconstruct stage: register, reconstruct.
#include <cstdio>
#include <optional>
#include <sstream>
#include <vector>

#include "app/commands.h"
#include "reconstruct/reconstruct_job.h"
#include "reconstruct/register_job.h"

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

void add_register(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "register",
      "Register all views at once (Ceres): point-to-plane between every overlapping pair, coarse to fine.\n"
      "Input: a session (depth or scanner points; initial poses from --calibration's turntable axis and\n"
      "the table angles, or the session's given poses) or Stanford range scans (--stanford CONF).\n"
      "Writes OUT/poses.json, OUT/report.json, OUT/views.csv, OUT/pairs.csv, OUT/convergence.csv/png\n"
      "(RMS and pose error against seconds) and, for --stanford, OUT/<CONF> in the input's own conventions.");
  struct Args {
    std::string session, stanford, calibration, out, mode = "free", perturb, fixed, voxels;
    uint64_t seed = 1;
    int threads = 0;
    bool no_flip = false;
    double sigma_angle = 0.2;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("session", a->session, "capture session folder");
  sub->add_option("--stanford", a->stanford, "Stanford .conf with its range scans beside it");
  sub->add_option("--calibration", a->calibration, "calibration file (turntable axis, intrinsics)");
  sub->add_option("--out", a->out, "output folder")->required();
  sub->add_option("--mode", a->mode,
                  "free (every pose free; slides reported) or turntable (rotation about the calibrated axis by the "
                  "table angle plus a small correction)")
      ->check(CLI::IsMember({"free", "turntable"}))
      ->capture_default_str();
  sub->add_option("--perturb", a->perturb, "DEG,M: start from the input poses turned by DEG and shifted by M metres");
  sub->add_option("--seed", a->seed, "random seed of --perturb")->capture_default_str();
  sub->add_option("--fixed", a->fixed, "name of the view held fixed (default: the first)");
  sub->add_option("--voxels", a->voxels, "coarse-to-fine voxel sizes in metres, e.g. 0.004,0.002,0.001 (default: from the extent)");
  sub->add_option("--table-sigma-deg", a->sigma_angle, "turntable mode: table angle repeatability")->capture_default_str();
  sub->add_option("--threads", a->threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->add_flag("--no-flip", a->no_flip, "do not try flagged views turned by 180 deg");
  sub->callback([a] {
    set_runner([a] {
      RegisterJob job;
      job.session = a->session;
      job.stanford_conf = a->stanford;
      job.calibration = a->calibration;
      job.out = a->out;
      job.seed = a->seed;
      job.fixed_name = a->fixed;
      job.options.mode = a->mode == "turntable" ? RegistrationMode::kTurntable : RegistrationMode::kFree;
      job.options.threads = a->threads;
      job.options.try_flip = !a->no_flip;
      if (!(a->sigma_angle > 0)) return error("--table-sigma-deg must be positive");
      job.table_sigma_deg = a->sigma_angle;
      if (!a->perturb.empty()) {
        auto p = parse_pair(a->perturb);
        if (!p) return error("--perturb expects DEG,M with two non-negative numbers, e.g. 5,0.005");
        job.perturb_deg = p->first;
        job.perturb_m = p->second;
      }
      for (const auto& item : comma_items(a->voxels)) {
        const auto v = positive_metres(item);
        if (!v) return error("--voxels: '" + item + "' is not a positive length in metres");
        job.options.voxel_m.push_back(*v);
      }
      auto r = run_register_job(job);
      if (!r) return error(r.error().message);
      return finish(*r, fs::path(a->out) / "report.json");
    });
  });
}

void add_reconstruct(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "reconstruct",
      "Fuse a session's registered views into a model of microfacet billboards.\n"
      "Depth is fused into a sparse signed-distance volume (OpenVDB); against a uniform backdrop the\n"
      "silhouettes add a visual hull, whose voxels that depth does not explain become fuzzy facets\n"
      "(hair, strands); without depth the hull alone gives the geometry. Every voxel with evidence becomes\n"
      "a facet; reliable voxels keep the voxel size, unreliable and fuzzy regions merge into facets twice\n"
      "as large. Each camera's image is stored with the distance to the fused surface along every ray.\n"
      "Poses: --poses, else the session's given poses, else --calibration's turntable axis and the table\n"
      "angles, else the synthetic rig's ground truth.\n"
      "Writes OUT/model.json, facets.bin, facet_cameras.bin, cameras/NNNN.exr (RGBA + Z), surface.ply\n"
      "and report.json (seconds per step, facets, memory, voxel sizes, predicted texel error, skipped work).");
  // Flags bind straight to the job: each default is the job's own.
  auto job = std::make_shared<ReconstructJob>();
  auto voxel = std::make_shared<std::string>("auto");
  auto geometry = std::make_shared<std::string>(geometry_name(job->geometry));
  auto holdout = std::make_shared<std::string>();
  sub->add_option("session", job->session, "capture session folder")->required();
  sub->add_option("--out", job->out, "model folder")->required();
  sub->add_option("--poses", job->poses, "registered poses (s2r register)");
  sub->add_option("--calibration", job->calibration, "calibration file (intrinsics, depth extrinsic, turntable axis)");
  sub->add_option("--voxel", *voxel,
                  "facet size w in metres, or 'auto': the largest w whose texel error bound (w/2) sin(gap/2) stays under "
                  "--target-error pixels at the cameras' distance, halved for reliable regions")
      ->capture_default_str();
  sub->add_option("--target-error", job->target_error_px, "on-screen texel error in pixels that --voxel auto keeps under")
      ->capture_default_str();
  sub->add_option("--geometry", *geometry,
                  "depth (fusion), hull (silhouettes only), both, or auto (depth, plus the hull against a uniform backdrop)")
      ->check(CLI::IsMember({"auto", "depth", "hull", "both"}))
      ->capture_default_str();
  sub->add_option("--holdout", *holdout, "I,J,...: frames left out entirely (for evaluation)");
  sub->add_option("--truncation", job->truncation_voxels, "signed-distance truncation in voxels")->capture_default_str();
  sub->add_flag_callback("--uniform", [job] { job->per_region = false; },
                         "one facet size everywhere (no larger facets for unreliable regions)");
  sub->add_flag_callback("--no-textures", [job] { job->textures = false; },
                         "do not write the per-camera RGBA + depth textures (the cameras' depth is then cast only where "
                         "the facets' visibility needs it)");
  sub->add_option("--threads", job->threads, "worker threads (0 = all cores)")->capture_default_str();
  sub->callback([=] {
    set_runner([=] {
      static const FlagNames flags = {{"target_error_px", "--target-error"}, {"truncation_voxels", "--truncation"},
                                      {"voxel_m", "--voxel"}, {"threads", "--threads"}, {"geometry", "--geometry"},
                                      {"holdout", "--holdout"}};
      job->geometry = *parse_geometry(*geometry);  // CLI11 checked the name
      if (*voxel != "auto") {
        job->voxel_m = positive_metres(*voxel);
        if (!job->voxel_m) return error("--voxel: '" + *voxel + "' is neither 'auto' nor a positive length in metres");
      }
      auto held = frame_list(*holdout, "--holdout");
      if (!held) return error(held.error().message);
      job->holdout = *held;
      auto r = run_reconstruct_job(*job);
      if (!r) return error(in_flag_terms(r.error(), flags));
      return finish(*r, job->out / "report.json");
    });
  });
}

}  // namespace

void add_reconstruct_commands(CLI::App& app) {
  add_register(app);
  add_reconstruct(app);
}

}  // namespace s2r::cli
