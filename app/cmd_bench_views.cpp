// s2r bench views: held-out views of every scene the product is judged on,
// one table. NeRF-synthetic lego (fit on train, every val view, full image on
// white as the field reports it), the rig bunny and fuzzy object (frames 5 and
// 17 held out), the Middlebury dino ring (frames 3, 7 and 11, each left out of
// its own model), the RealSense bear (frame 3 held out, the poses from the
// table's dot markers; the registration's distance from them reported).
// Billboards, the textured patch mesh and the textured fused surface (the
// hull's boundary where there is no depth) in the same run; build seconds, model bytes, frame ms at the
// images' size.
#include <algorithm>
#include <cstdio>
#include <map>
#include <optional>
#include <numeric>

#include <spdlog/fmt/fmt.h>

#include "app/run.h"
#include "calibrate/table_markers.h"
#include "capture/import_datasets.h"
#include "capture/synth_rig.h"
#include "core/paths.h"
#include "core/sweep.h"
#include "reconstruct/reconstruct_job.h"
#include "reconstruct/register_job.h"
#include "render/model_eval.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {

// One scene's models (one, or one per left-out view) and their evaluations.
struct SceneRun {
  std::string scene;
  double fit_seconds = 0;    // each model's fit budget
  double fit_ssim = 0;       // its loss's SSIM weight (reconstruct --fit-ssim)
  std::string fit_loss;      // its colour term (reconstruct --fit-loss)
  std::vector<std::pair<double, EvalSummary>> snapshots;  // lego: the fit at its marks, evaluated
  double build_seconds = 0;  // every model's reconstruct, summed
  double fit_spent = 0;      // of which the fits' seconds
  double model_bytes = 0;    // per model, summed (the mean: over the evals)
  double fit_bytes = 0;      // of which splats.bin
  double photo_bytes = 0;    // of which the camera textures and meshes (what only billboards and meshes read)
  std::map<std::string, double> render_seconds;  // per method: one `s2r render` of a held-out view, load to PNG
  std::vector<EvalSummary> evals;
  std::string size;          // the images' size
  std::map<std::string, double> errors;  // the scene's own figures for the report (named with the scene)
};

double folder_bytes(const fs::path& dir) {
  std::error_code ec;
  double bytes = 0;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    if (it->is_regular_file(ec) && !it->path().filename().string().starts_with("splats_"))  // the fit's snapshots
      bytes += double(it->file_size(ec));
  return bytes;
}

std::vector<int> frames_every(int count, int step) {
  std::vector<int> f;
  for (int i = 0; i < count; i += std::max(1, step)) f.push_back(i);
  return f;
}

// Reconstructs `job`, then evaluates `frames` of `eval_session` with the fit,
// billboards, the textured patch mesh and the textured fused surface (the
// depth's surface, or without depth the hull's boundary).
Status build_and_eval(SceneRun& run, ReconstructJob job, const FrameSource& source, const std::vector<int>& frames,
                      const fs::path& eval_out) {
  job.fit_seconds = run.fit_seconds;
  job.fit_ssim_weight = run.fit_ssim;
  job.fit_loss = run.fit_loss;
  auto built = run_reconstruct_job(job);
  if (!built) return std::unexpected(with_context(built.error(), run.scene + ": reconstruct"));
  run.build_seconds += built->seconds;
  if (built->fit) run.fit_spent += built->fit->seconds;
  run.model_bytes += folder_bytes(job.out);
  std::error_code ec;
  if (const auto b = fs::file_size(job.out / "splats.bin", ec); !ec) run.fit_bytes += double(b);
  run.photo_bytes += folder_bytes(job.out / "cameras");
  for (const char* mesh : {"patches.ply", "surface.ply"})
    if (const auto b = fs::file_size(job.out / mesh, ec); !ec) run.photo_bytes += double(b);
  EvalJob e;
  e.model = job.out;
  e.source = source;
  e.frames = frames;
  e.out = eval_out;
  e.only = {"fitted", "billboards", "mesh", "surface"};
  auto ev = run_eval_job(e);
  if (!ev) return std::unexpected(with_context(ev.error(), run.scene + ": eval"));
  std::fprintf(stderr, "%s: %s\n", run.scene.c_str(), ev->brief().substr(0, 200).c_str());
  // A user's `s2r render` of one held-out view with each method, the first
  // model only: loading the model, drawing, writing the PNG.
  if (run.evals.empty() && !frames.empty())
    for (const auto& [method, geometry] : {std::pair{"fitted", DrawOptions::Geometry::kSplats},
                                           std::pair{"billboards", DrawOptions::Geometry::kBillboards}}) {
      if (!ev->method(method)) continue;
      RenderJob r;
      r.model = job.out;
      r.view = frames.front();
      r.source = source;
      r.draw.geometry = geometry;
      r.out = eval_out / (std::string("render_") + method + ".png");
      auto rs = run_render_job(r);
      if (!rs) return std::unexpected(with_context(rs.error(), run.scene + ": render"));
      run.render_seconds[method] = rs->seconds;
    }
  run.evals.push_back(std::move(*ev));
  return {};
}

Result<SceneRun> lego(const fs::path& out, int views, const ViewsFit& fit) {
  SceneRun run{"lego", fit.lego, fit.ssim, fit.loss};
  const fs::path data = data_dir() / "nerf_synthetic_lego";
  if (!fs::exists(data / "transforms_train.json")) return fail(ErrorCode::not_found, "no lego in " + data.string());
  for (const char* split : {"train", "val"}) {
    fs::remove_all(out / split);
    ImportOptions o;
    o.split = split;
    if (auto r = import_dataset("nerf", data, out / split, o); !r) return std::unexpected(r.error());
  }
  ReconstructJob job;
  job.session = out / "train";
  job.out = out / "model";
  job.geometry = Geometry::hull;
  run.size = "800x800";
  for (double m : {60.0, 300.0, 600.0, 900.0, 1200.0})
    if (m < fit.lego) job.fit_snapshots.push_back(m);
  const auto frames = frames_every(100, 100 / std::clamp(views, 1, 100));
  if (auto st = build_and_eval(run, job, {out / "val"}, frames, out / "eval"); !st) return std::unexpected(st.error());
  // The fit as it stood at each mark: PSNR against the fit's seconds.
  for (double m : job.fit_snapshots) {
    EvalJob e;
    e.model = job.out;
    e.source = {out / "val"};
    e.frames = frames;
    e.out = out / fmt::format("eval_fit_{:.0f}s", m);
    e.only = {"fitted"};
    e.splats = job.out / fmt::format("splats_{:.0f}s.bin", m);
    auto ev = run_eval_job(e);
    if (!ev) return std::unexpected(with_context(ev.error(), "lego: the fit at " + std::to_string(int(m)) + " s"));
    run.snapshots.emplace_back(m, std::move(*ev));
  }
  return run;
}

Result<SceneRun> rig(const fs::path& out, const std::string& scene, const ViewsFit& fit) {
  SceneRun run{"rig " + scene, fit.others, fit.ssim, fit.loss};
  SynthOptions so;
  so.scene = scene;
  so.views = 24;
  so.seed = 3;
  fs::remove_all(out / "session");
  if (auto s = synth_session(so, out / "session"); !s) return std::unexpected(s.error());
  run.size = fmt::format("{}x{}", so.width, so.height);
  ReconstructJob job;
  job.session = out / "session";
  job.out = out / "model";
  job.holdout = {5, 17};
  if (auto st = build_and_eval(run, job, {out / "session"}, {5, 17}, out / "eval"); !st) return std::unexpected(st.error());
  return run;
}

Result<SceneRun> dino(const fs::path& out, const ViewsFit& fit) {
  SceneRun run{"dino ring", fit.others, fit.ssim, fit.loss};
  fs::remove_all(out / "session");
  if (auto r = import_dataset("middlebury", data_dir() / "middlebury_dino_ring", out / "session", {}); !r)
    return std::unexpected(r.error());
  run.size = "640x480";
  for (int held : {3, 7, 11}) {
    ReconstructJob job;
    job.session = out / "session";
    job.out = out / fmt::format("model_{}", held);
    job.geometry = Geometry::hull;
    job.holdout = {held};
    if (auto st = build_and_eval(run, job, {out / "session"}, {held}, out / fmt::format("eval_{}", held)); !st)
      return std::unexpected(st.error());
  }
  return run;
}

Result<SceneRun> bear(const fs::path& out, const ViewsFit& fit) {
  SceneRun run{"bear", fit.others, fit.ssim, fit.loss};
  const fs::path session = out / "session", cal = out / "calibration.json", reg = out / "register";
  fs::remove_all(session);
  if (auto r = import_dataset("realsense", data_dir() / "realsense_d435_bear" / "bear", session, {}); !r)
    return std::unexpected(r.error());
  if (auto r = run_markers_job(session, cal, {}); !r) return std::unexpected(with_context(r.error(), "bear: markers"));
  RegisterJob rj;
  rj.session = session;
  rj.calibration = cal;
  rj.out = reg;
  // The registration runs as the check it is: how far the depth moves each
  // view from its dots' angle. The model and the held-out camera take the
  // dots' poses: the depth camera's point-to-plane registration turns the
  // views up to 1.2 deg off them, and with its poses every frame held out in
  // turn draws 0.2-1.5 dB worse through the textured meshes (the fitted
  // billboards at frame 3, a 300-s fit each: 25.51 dB / SSIM 0.867 on the
  // registration's poses, 26.94 / 0.891 on the dots').
  auto r = run_register_job(rj);
  if (!r) return std::unexpected(with_context(r.error(), "bear: register"));
  if (r->table) {
    run.errors["register_max_turn_from_table_deg"] = r->table->max_turn_deg;
    run.errors["register_rms_turn_from_table_deg"] = r->table->rms_turn_deg;
  }
  run.size = "640x480";
  ReconstructJob job;
  job.session = session;
  job.calibration = cal;
  job.out = out / "model";
  job.holdout = {3};
  if (auto st = build_and_eval(run, job, {session, {}, cal}, {3}, out / "eval"); !st)
    return std::unexpected(st.error());
  return run;
}

// A method's figures over a scene's evaluations, weighted by their views.
struct Pooled {
  double full_psnr = 0, full_ssim = 0, psnr = 0, ssim = 0, frame_ms = 0;
  size_t views = 0;
  // Where every evaluation had true mattes (lego's alpha): the coverage's
  // error over the silhouette's band and the colour's PSNR there.
  std::optional<double> matte_edge_mae, edge_psnr;
};
std::optional<Pooled> pooled(const SceneRun& run, const std::string& method) {
  Pooled p;
  for (const auto& e : run.evals) {
    const EvalMethodFigures* m = e.method(method);
    if (!m) return std::nullopt;
    const double n = double(e.views);
    p.full_psnr += n * m->full_psnr_db, p.full_ssim += n * m->full_ssim;
    p.psnr += n * m->psnr_db, p.ssim += n * m->ssim, p.frame_ms += n * m->frame_ms;
    p.views += e.views;
  }
  if (!p.views) return std::nullopt;
  for (double* x : {&p.full_psnr, &p.full_ssim, &p.psnr, &p.ssim, &p.frame_ms}) *x /= double(p.views);
  if (std::all_of(run.evals.begin(), run.evals.end(), [&](const EvalSummary& e) { return e.method(method)->matte_edge_mae.has_value(); })) {
    double mae = 0, edge = 0;
    for (const auto& e : run.evals) {
      const EvalMethodFigures* m = e.method(method);
      mae += double(e.views) * *m->matte_edge_mae, edge += double(e.views) * *m->edge_psnr_db;
    }
    p.matte_edge_mae = mae / double(p.views), p.edge_psnr = edge / double(p.views);
  }
  return p;
}

}  // namespace

int bench_views(const fs::path& out, int lego_views, const ViewsFit& fit, const std::vector<std::string>& only) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.views";
  std::error_code ec;
  fs::create_directories(out, ec);
  std::vector<std::pair<std::string, std::function<Result<SceneRun>()>>> scenes = {
      {"lego", [&] { return lego(out / "lego", lego_views, fit); }},
      {"bunny", [&] { return rig(out / "bunny", "bunny", fit); }},
      {"fuzzy", [&] { return rig(out / "fuzzy", "fuzzy", fit); }},
      {"dino", [&] { return dino(out / "dino", fit); }},
      {"bear", [&] { return bear(out / "bear", fit); }}};
  SweepTable fit_curve;  // lego: held-out PSNR of the fit against its seconds
  fit_curve.columns = {"fit_seconds", "full_psnr_db", "full_ssim"};
  SweepTable t;
  t.columns = {"build_seconds", "full_psnr_db", "full_ssim", "psnr_db_masked", "ssim_masked", "frame_ms", "model_mib", "views"};
  for (const auto& [name, make] : scenes) {
    if (!only.empty() && std::find(only.begin(), only.end(), name) == only.end()) {
      rep.skipped["scene_" + name + "_not_asked"] = 1;
      continue;
    }
    auto run = make();
    if (!run) {
      rep.warnings.push_back(name + ": " + run.error().message);
      std::fprintf(stderr, "%s: left out: %s\n", name.c_str(), run.error().message.c_str());
      continue;
    }
    for (const auto& [key, value] : run->errors) rep.errors[name + "_" + key] = value;
    const double models = double(std::max<size_t>(1, run->evals.size()));
    for (const auto& [m, ev] : run->snapshots)
      if (const EvalMethodFigures* f = ev.method("fitted")) {
        fit_curve.rows.push_back({m, f->full_psnr_db, f->full_ssim});
        rep.errors[fmt::format("full_psnr_db_{}_fitted_at_{:.0f}s", name, m)] = f->full_psnr_db;
      }
    if (auto p = pooled(*run, "fitted"); p && !run->snapshots.empty()) fit_curve.rows.push_back({run->fit_seconds, p->full_psnr, p->full_ssim});
    for (const std::string method : {"fitted", "billboards", "mesh", "surface"}) {
      auto p = pooled(*run, method);
      if (!p) continue;
      t.row_labels.push_back(run->scene + " " + run->size + ": " + method);
      // The billboards and the meshes need neither the fit's seconds nor its
      // file; the fitted view reads neither the camera textures nor the
      // meshes (what `reconstruct --no-textures --fit` writes, less the
      // meshes).
      const bool fitted = method == "fitted";
      const double mib = (run->model_bytes - (fitted ? run->photo_bytes : run->fit_bytes)) / models / (1 << 20);
      t.rows.push_back({run->build_seconds - (fitted ? 0.0 : run->fit_spent), p->full_psnr, p->full_ssim, p->psnr, p->ssim,
                        p->frame_ms, mib, double(p->views)});
      rep.counts[fmt::format("model_mib_{}_{}", name, method)] = mib;
      if (auto it = run->render_seconds.find(method); it != run->render_seconds.end())
        rep.counts[fmt::format("render_seconds_{}_{}", name, method)] = it->second;
      rep.errors[fmt::format("full_psnr_db_{}_{}", name, method)] = p->full_psnr;
      rep.errors[fmt::format("full_ssim_{}_{}", name, method)] = p->full_ssim;
      rep.errors[fmt::format("psnr_db_masked_{}_{}", name, method)] = p->psnr;
      rep.counts[fmt::format("frame_ms_{}_{}", name, method)] = p->frame_ms;
      if (p->matte_edge_mae) {
        rep.errors[fmt::format("matte_edge_mae_{}_{}", name, method)] = *p->matte_edge_mae;
        rep.errors[fmt::format("edge_psnr_db_{}_{}", name, method)] = *p->edge_psnr;
        std::fprintf(stderr, "%s, %s: against the true matte, silhouette band: mean |alpha error| %.3f, colour %.2f dB\n",
                     run->scene.c_str(), method.c_str(), *p->matte_edge_mae, *p->edge_psnr);
      }
      std::fprintf(stderr, "%s, %s: full-image PSNR %.2f dB (SSIM %.3f), masked %.2f dB, %zu views, build %.1f s, %.1f ms a frame, "
                   "%.1f MiB read\n", run->scene.c_str(), method.c_str(), p->full_psnr, p->full_ssim, p->psnr, p->views,
                   t.rows.back()[0], p->frame_ms, mib);
    }
    rep.counts["build_seconds_" + name] = run->build_seconds;
    rep.counts["fit_seconds_" + name] = run->fit_spent;
    rep.counts["model_mib_" + name] = run->model_bytes / models / (1 << 20);
  }
  if (t.rows.empty()) return error("bench views: no scene could be built (" + std::to_string(rep.warnings.size()) + " left out)");
  if (auto st = t.write_csv(out / "views.csv"); !st) return error(st.error().message);
  PlotSpec spec{"held-out full-image PSNR against build seconds (each point a scene and method)", "build seconds",
                "PSNR (dB)", "build_seconds", {"full_psnr_db"}, true, true};
  if (auto st = plot_png(t, spec, out / "views.png"); !st) rep.warnings.push_back(st.error().message);
  if (!fit_curve.rows.empty()) {
    if (auto st = fit_curve.write_csv(out / "fit.csv"); !st) return error(st.error().message);
    PlotSpec fs{"lego val: fitted billboards' full-image PSNR against the fit's seconds", "fit seconds", "PSNR (dB)",
                "fit_seconds", {"full_psnr_db"}, false, false};
    if (auto st = plot_png(fit_curve, fs, out / "fit.png"); !st) rep.warnings.push_back(st.error().message);
  }
  rep.params["lego_views"] = double(lego_views);
  rep.params["fit_seconds_lego"] = fit.lego;
  rep.params["fit_seconds_others"] = fit.others;
  rep.params["fit_ssim_weight"] = fit.ssim;
  rep.params["fit_loss"] = fit.loss;
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

}  // namespace s2r::cli
