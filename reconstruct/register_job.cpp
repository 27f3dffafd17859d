#include "reconstruct/register_job.h"

#include <cmath>

#include <fmt/format.h>

#include "capture/ground_truth.h"
#include "core/sweep.h"
#include "reconstruct/poses.h"
#include "reconstruct/registration_input.h"

namespace s2r {
namespace fs = std::filesystem;

Status RegisterJob::validate() const {
  if (session.empty() == stanford_conf.empty())
    return fail(ErrorCode::invalid, "stanford_conf: give either a session or Stanford scans (not both)");
  if (out.empty()) return fail(ErrorCode::invalid, "out: an output folder is required");
  if (!(table_sigma_deg > 0) || !std::isfinite(table_sigma_deg))
    return fail(ErrorCode::invalid, "table_sigma_deg: must be > 0 degrees");
  if (perturb_deg && !(*perturb_deg >= 0 && std::isfinite(*perturb_deg)))
    return fail(ErrorCode::invalid, "perturb: the angle must be >= 0 degrees");
  if (perturb_m && !(*perturb_m >= 0 && std::isfinite(*perturb_m)))
    return fail(ErrorCode::invalid, "perturb: the shift must be >= 0 metres");
  for (double v : options.voxel_m)
    if (!(v > 0) || !std::isfinite(v)) return fail(ErrorCode::invalid, "voxel_m: every size must be a positive length");
  if (options.threads < 0) return fail(ErrorCode::invalid, "threads: must be >= 0 (0 = all cores)");
  return {};
}

namespace {

// The views as loaded, with the ground truth of a synthetic session.
struct LoadedViews {
  RegistrationInput in;
  std::optional<GroundTruth> truth;
  std::string source;
};

Result<LoadedViews> load_views(const RegisterJob& job) {
  std::optional<Calibration> cal;
  if (!job.calibration.empty()) {
    auto c = load_calibration(job.calibration);
    if (!c) return std::unexpected(c.error());
    cal = *c;
  }
  LoadedViews lv;
  Result<RegistrationInput> in = fail("no input");
  if (!job.stanford_conf.empty()) {
    in = load_stanford_views(job.stanford_conf, {});
    lv.source = job.stanford_conf.string();
  } else {
    auto s = load_session(job.session);
    if (!s) return std::unexpected(s.error());
    in = load_session_views(*s, cal ? &*cal : nullptr, {});
    lv.source = job.session.string();
    if (auto t = load_ground_truth(job.session); t) lv.truth = std::move(*t);
  }
  if (!in) return std::unexpected(in.error());
  lv.in = std::move(*in);
  return lv;
}

// The options with what the input decides: the fixed view by name, the
// turntable prior of a calibrated axis.
Result<RegistrationOptions> input_options(const RegisterJob& job, const RegistrationInput& in) {
  RegistrationOptions o = job.options;
  if (!job.fixed_name.empty()) {
    o.fixed_view = -1;
    for (size_t i = 0; i < in.views.size(); ++i)
      if (in.views[i].name == job.fixed_name) o.fixed_view = static_cast<int>(i);
    if (o.fixed_view < 0) return fail(ErrorCode::invalid, "fixed_name: '" + job.fixed_name + "' is not one of the views");
  }
  if (o.mode == RegistrationMode::kTurntable && !in.turntable)
    return fail(ErrorCode::invalid, "mode: turntable needs a calibration with a turntable axis");
  if (in.turntable && !o.turntable) {
    o.turntable = in.turntable;
    o.turntable->sigma_angle_deg = job.table_sigma_deg;
  }
  return o;
}

// The poses to measure against: ground truth of a synthetic session, else
// the input's own poses when the start was perturbed; none otherwise.
std::optional<std::vector<Eigen::Isometry3d>> reference_poses(const RegisterJob& job, const LoadedViews& lv,
                                                              Report& report) {
  if (lv.truth && lv.truth->world_from_camera.size() >= lv.in.frames.size()) {
    std::vector<Eigen::Isometry3d> ref;
    for (int f : lv.in.frames) ref.push_back(lv.truth->world_from_camera.at(static_cast<size_t>(f)));
    report.params["reference"] = "ground truth (synthetic rig)";
    return ref;
  }
  if (job.perturb_deg || job.perturb_m) {
    report.params["reference"] = "the input's poses (before perturbation)";
    return lv.in.given;
  }
  return std::nullopt;
}

}  // namespace

TableAgreement table_agreement(const std::vector<Eigen::Isometry3d>& poses, const std::vector<Eigen::Isometry3d>& table,
                               const Eigen::Vector3d& axis) {
  TableAgreement a;
  const Eigen::Vector3d d = axis.normalized();
  double sum = 0;
  for (size_t i = 0; i < poses.size() && i < table.size(); ++i) {
    // The world-frame rotation from the table's pose to the registered one,
    // split into a twist about the axis and the swing left (the tilt).
    Eigen::Quaterniond q(poses[i].linear() * table[i].linear().transpose());
    q.normalize();
    if (q.w() < 0) q.coeffs() = -q.coeffs();
    const double along = q.vec().dot(d);
    const double turn = 2 * std::atan2(along, q.w());
    const Eigen::Quaterniond twist(Eigen::AngleAxisd(turn, d));
    const Eigen::Quaterniond swing = q * twist.conjugate();
    const double tilt = 2 * std::atan2(swing.vec().norm(), std::abs(swing.w()));
    const double turn_deg = turn * 180 / M_PI, tilt_deg = tilt * 180 / M_PI;
    a.turn_deg.push_back(turn_deg);
    a.tilt_deg.push_back(tilt_deg);
    a.max_turn_deg = std::max(a.max_turn_deg, std::abs(turn_deg));
    a.max_tilt_deg = std::max(a.max_tilt_deg, tilt_deg);
    sum += turn_deg * turn_deg;
  }
  if (!a.turn_deg.empty()) a.rms_turn_deg = std::sqrt(sum / double(a.turn_deg.size()));
  return a;
}

namespace {

// poses.json, the .conf of Stanford input, and the per-view and per-pair tables.
Status write_results(const RegisterJob& job, const LoadedViews& lv, const std::vector<RegistrationView>& views,
                     const RegistrationResult& r, const std::optional<PoseError>& view_error,
                     const std::optional<TableAgreement>& table, Report& report) {
  std::error_code ec;
  fs::create_directories(job.out, ec);
  if (ec) return fail("cannot create '" + job.out.string() + "': " + ec.message());
  Poses poses;
  poses.session = lv.source;
  poses.rms_m = r.rms_m;
  for (size_t i = 0; i < views.size(); ++i) {
    FramePose fp;
    fp.index = lv.in.frames[i];
    fp.world_from_camera = r.poses[i];
    fp.residual_rms_m = r.views[i].rms_m;
    fp.flagged = r.views[i].flagged;
    fp.note = r.views[i].note;
    poses.frames.push_back(fp);
  }
  if (auto st = save_poses(job.out / "poses.json", poses); !st) return st;
  if (lv.in.conf) {
    StanfordConf conf = *lv.in.conf;
    for (size_t i = 0; i < conf.scans.size() && i < r.poses.size(); ++i) conf.scans[i].world_from_scan = r.poses[i];
    const fs::path conf_out = job.out / job.stanford_conf.filename();
    if (auto st = write_stanford_conf(conf_out, conf); !st) return st;
    report.params["conf"] = conf_out.string();
  }
  SweepTable vt;
  vt.columns = {"view", "rms_mm", "overlap", "pairs", "flagged", "flipped", "rot_err_deg", "trans_err_mm"};
  if (table) vt.columns.insert(vt.columns.end(), {"turn_from_table_deg", "tilt_from_table_deg"});
  for (size_t i = 0; i < views.size(); ++i) {
    const auto& v = r.views[i];
    vt.row_labels.push_back(views[i].name);
    vt.rows.push_back({double(i), 1e3 * v.rms_m, v.overlap, double(v.pairs), double(v.flagged), double(v.flipped),
                       view_error ? view_error->rotation_deg[i] : -1,
                       view_error ? 1e3 * view_error->translation_m[i] : -1});
    if (table) vt.rows.back().insert(vt.rows.back().end(), {table->turn_deg[i], table->tilt_deg[i]});
  }
  if (auto st = vt.write_csv(job.out / "views.csv"); !st) return st;
  SweepTable pt;
  pt.columns = {"a", "b", "overlap", "rms_mm", "correspondences"};
  for (const auto& p : r.pairs) pt.rows.push_back({double(p.a), double(p.b), p.overlap, 1e3 * p.rms_m, double(p.correspondences)});
  return pt.write_csv(job.out / "pairs.csv");
}

}  // namespace

// Load the views, resolve the options, perturb the start, register (each
// round's error against the reference into the convergence table), write.
Result<RegisterSummary> run_register_job(const RegisterJob& job) {
  Stopwatch clock;
  RegisterSummary sum;
  Report& report = sum.report;
  report.stage = "register";
  if (auto st = job.validate(); !st) return std::unexpected(st.error());
  auto lv = load_views(job);
  if (!lv) return std::unexpected(lv.error());
  RegistrationInput& in = lv->in;
  report.seconds = clock.seconds();
  report.params["input"] = lv->source;
  report.counts["points_in"] = double(in.prep.input);
  report.counts["points_kept"] = double(in.prep.kept);
  report.skipped["outlier_points"] = double(in.prep.outliers);
  report.skipped["points_without_normal"] = double(in.prep.no_normal);
  for (const auto& n : in.notes) report.warnings.push_back(n);
  auto options = input_options(job, in);
  if (!options) return std::unexpected(options.error());
  RegistrationOptions& o = *options;

  const Eigen::Vector3d centre = points_centre(in.views, in.given);
  std::vector<Eigen::Isometry3d> start = in.given;
  if (job.perturb_deg || job.perturb_m) {
    start = perturb_poses(in.given, job.perturb_deg.value_or(0), job.perturb_m.value_or(0), job.seed, centre,
                          o.fixed_view);
    report.params["perturb"] = fmt::format("{} deg, {} m, seed {}", job.perturb_deg.value_or(0),
                                           job.perturb_m.value_or(0), job.seed);
  }
  std::vector<RegistrationView> views = std::move(in.views);
  for (size_t i = 0; i < views.size(); ++i) views[i].initial = start[i];
  const std::optional<std::vector<Eigen::Isometry3d>> reference = reference_poses(job, *lv, report);
  SweepTable table;
  table.columns = {"round", "level", "voxel_m", "iterations", "seconds", "rms_mm", "max_rot_err_deg",
                   "max_trans_err_mm"};
  o.on_round = [&](const RegistrationRound& r) {
    double rot = -1, tr = -1;
    if (reference) {
      const PoseError e = pose_error(r.poses, *reference, centre, o.fixed_view);
      rot = e.max_rotation_deg;
      tr = 1e3 * e.max_translation_m;
    }
    table.rows.push_back({double(table.rows.size()), double(r.level), r.voxel_m, double(r.solver_iterations),
                          r.seconds, 1e3 * r.rms_m, rot, tr});
  };
  auto r = register_views(views, o);
  if (!r) return std::unexpected(r.error());
  add_to_report(*r, views, report);
  report.params["mode"] = std::string(o.mode == RegistrationMode::kFree ? "free" : "turntable");
  report.params["fixed_view"] = views[static_cast<size_t>(o.fixed_view)].name;
  report.counts["register_seconds"] = r->seconds;
  sum.mode = o.mode;
  sum.fixed_view = views[static_cast<size_t>(o.fixed_view)].name;
  sum.views = views.size();
  sum.points_in = in.prep.input, sum.points_kept = in.prep.kept;
  sum.rms_m = r->rms_m, sum.iterations = r->iterations, sum.rounds = r->rounds;
  sum.register_seconds = r->seconds;
  // A calibrated turntable gives every view a table angle of its own (the
  // markers' or the reported steps'): how far the registration moved each
  // view from it, as a turn about the axis and a tilt off it. Two
  // measurements that agree (the dots and the depth) leave little doubt
  // about a held-out view's pose; a large turn is a slide about the axis
  // (a round object) or a wrong table angle.
  if (in.turntable && !job.perturb_deg && !job.perturb_m) {
    const TableAgreement a = table_agreement(r->poses, in.given, in.turntable->direction);
    report.errors["max_turn_from_table_deg"] = a.max_turn_deg;
    report.errors["rms_turn_from_table_deg"] = a.rms_turn_deg;
    report.errors["max_tilt_from_table_deg"] = a.max_tilt_deg;
    sum.table = a;
  }
  std::optional<PoseError> view_error;
  if (reference) {
    const PoseError e0 = pose_error(start, *reference, centre, o.fixed_view);
    const PoseError e = pose_error(r->poses, *reference, centre, o.fixed_view);
    sum.start_error = e0, sum.error = e;
    report.errors["start_max_rotation_deg"] = e0.max_rotation_deg;
    report.errors["start_max_translation_m"] = e0.max_translation_m;
    report.errors["max_rotation_deg"] = e.max_rotation_deg;
    report.errors["max_translation_m"] = e.max_translation_m;
    view_error = e;
  }
  if (auto st = write_results(job, *lv, views, *r, view_error, sum.table, report); !st) return std::unexpected(st.error());
  if (auto st = table.write_csv(job.out / "convergence.csv"); !st) return std::unexpected(st.error());
  PlotSpec spec{"registration: error against run time", "seconds", "RMS point-to-plane (mm) / pose error",
                "seconds", {"rms_mm"}};
  if (reference) spec.y = {"rms_mm", "max_rot_err_deg", "max_trans_err_mm"};
  if (auto st = plot_png(table, spec, job.out / "convergence.png"); !st) report.warnings.push_back(st.error().message);
  sum.seconds = report.seconds = clock.seconds();
  return sum;
}

}  // namespace s2r
