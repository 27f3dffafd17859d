// `s2r bench STAGE --out DIR`: error-vs-time sweeps, CSV + PNG + report.json,
// with a peer measured in the same run so figures are ratios.
#include <algorithm>
#include <cstdio>
#include <numbers>
#include <thread>

#include "app/run.h"
#include "calibrate/intrinsics.h"
#include "calibrate/turntable_axis.h"
#include "capture/pixel_formats.h"
#include "capture/session.h"
#include "capture/synth_rig.h"
#include "core/image_io.h"
#include "core/parallel.h"
#include "core/paths.h"
#include "core/shell.h"
#include "core/sweep.h"
#include "reconstruct/icp_peer.h"
#include "reconstruct/microfacets.h"
#include "reconstruct/model.h"
#include "reconstruct/reconstruct_job.h"
#include "reconstruct/rig_eval.h"
#include "render/model_eval.h"
#include "render/envmap.h"
#include "render/glossy_renderer.h"
#include "render/gl_context.h"
#include "render/material_lod.h"
#include "core/image_metrics.h"
#include "render/raytrace_job.h"
#include "core/atomic_file.h"

#include <nlohmann/json.hpp>
#include <spdlog/fmt/fmt.h>
#include "reconstruct/registration_input.h"

namespace s2r::cli {
namespace fs = std::filesystem;

namespace {

// Rig render time vs image size; peer: the same renders on one thread.
int bench_rig(const fs::path& out, int repeats, const std::string& scene) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.rig";
  SweepTable t;
  t.columns = {"pixels", "width", "height", "threads", "seconds_per_view", "mrays_per_second", "depth_rms_mm"};
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const std::pair<int, int> sizes[] = {{160, 120}, {320, 240}, {640, 480}, {960, 720}, {1280, 960}};
  for (auto [w, h] : sizes) {
    for (int threads : {1, cores}) {
      if (threads == 1 && cores == 1 && !t.rows.empty() && t.rows.back()[3] == 1) continue;
      SynthOptions o;
      o.scene = scene;
      o.views = 8;
      o.width = w;
      o.height = h;
      o.threads = threads;
      auto rig = SynthRig::create(o);
      if (!rig) return error(rig.error().message);
      std::vector<double> secs;
      size_t rays = 0;
      double sq = 0, n = 0;
      for (int r = 0; r < repeats; ++r) {
        Stopwatch sw;
        SynthView v = (*rig)->render(r % o.views);
        secs.push_back(sw.seconds());
        rays = v.rays;
        for (size_t p = 0; p < v.depth.pixels(); ++p)
          if (v.depth.data[p]) {
            const double e = v.depth.data[p] * o.depth_unit_m - v.gt_depth.data[p];
            sq += e * e;
            ++n;
          }
      }
      const double s = median(secs);
      t.rows.push_back({double(w) * h, double(w), double(h), double(threads), s, rays / s / 1e6,
                        n > 0 ? 1000 * std::sqrt(sq / n) : 0});
      t.row_labels.push_back(threads == 1 ? "1 thread (peer)" : std::to_string(threads) + " threads");
      std::fprintf(stderr, "rig %dx%d threads %d: %.3f s/view (median of %d), %.2f Mrays/s\n", w, h, threads, s,
                   repeats, rays / s / 1e6);
    }
  }
  if (auto st = t.write_csv(out / "rig.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Synthetic rig: render time per view vs image size (" + scene + ")", "pixels per view",
                "seconds per view (median)", "pixels", {"seconds_per_view"}, true, true, true};
  if (auto st = plot_png(t, spec, out / "rig.png"); !st) rep.warnings.push_back(st.error().message);
  // Ratio single-thread / all threads at the largest size, measured in this run.
  const auto& last = t.rows.back();
  for (const auto& r : t.rows)
    if (r[0] == last[0] && r[3] == 1 && last[3] != 1) rep.errors["speedup_all_threads_vs_one"] = r[4] / last[4];
  rep.counts["sizes"] = std::size(sizes);
  rep.counts["repeats"] = repeats;
  rep.params["scene"] = scene;
  rep.params["csv"] = (out / "rig.csv").string();
  rep.params["plot"] = (out / "rig.png").string();
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// Per-frame capture overhead on one core: decode of the raw frame + the
// atomic PNG write of a session frame, against the 30 fps frame period.
int bench_capture(const fs::path& out, int repeats) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.capture";
  SweepTable t;
  t.columns = {"pixels", "width", "height", "decode_ms", "write_ms", "overhead_ms", "period_over_overhead"};
  struct Case { const char* name; uint32_t fourcc; int w, h; PngEffort effort; };
  // The capture path (fast PNG) and, as peers in the same run, MJPEG input and compact PNG.
  const Case cases[] = {{"YUYV 1280x720", kFourccYUYV, 1280, 720, PngEffort::kFast},
                        {"Z16 848x480", kFourccZ16, 848, 480, PngEffort::kFast},
                        {"MJPEG 1280x720 (peer)", kFourccMJPG, 1280, 720, PngEffort::kFast},
                        {"YUYV 1280x720 compact PNG (peer)", kFourccYUYV, 1280, 720, PngEffort::kCompact}};
  const fs::path scratch = out / "scratch";
  for (const auto& c : cases) {
    SynthOptions o;
    o.scene = "blob";
    o.width = c.w;
    o.height = c.h;
    o.spp = 1;
    auto rig = SynthRig::create(o);
    if (!rig) return error(rig.error().message);
    const SynthView v = (*rig)->render(0);
    const PngEffort effort = c.effort;
    const std::string raw = c.fourcc == kFourccYUYV ? rgb_to_yuyv(v.color)
                            : c.fourcc == kFourccMJPG ? rgb_to_mjpeg(v.color)
                                                      : depth_to_z16(v.depth);
    std::vector<double> dec, wr;
    for (int i = 0; i < repeats; ++i) {
      Stopwatch sw;
      Status st;
      if (c.fourcc == kFourccZ16) {
        auto d = z16_to_depth(raw, c.w, c.h);
        if (!d) return error(d.error().message);
        dec.push_back(sw.seconds() * 1e3);
        Stopwatch sw2;
        st = write_image(scratch / frame_file_name(i, "png"), *d, effort);
        wr.push_back(sw2.seconds() * 1e3);
      } else {
        auto rgb = c.fourcc == kFourccYUYV ? yuyv_to_rgb(raw, c.w, c.h) : mjpeg_to_rgb(raw, c.w, c.h);
        if (!rgb) return error(rgb.error().message);
        dec.push_back(sw.seconds() * 1e3);
        Stopwatch sw2;
        st = write_image(scratch / frame_file_name(i, "png"), *rgb, effort);
        wr.push_back(sw2.seconds() * 1e3);
      }
      if (!st) return error(st.error().message);
    }
    const double d = median(dec), w = median(wr);
    t.rows.push_back({double(c.w) * c.h, double(c.w), double(c.h), d, w, d + w, (1000.0 / 30.0) / (d + w)});
    t.row_labels.push_back(c.name);
    std::fprintf(stderr, "%-34s decode %.2f ms + write %.2f ms = %.2f ms per frame; 30 fps period / overhead = %.2f\n",
                 c.name, d, w, d + w, (1000.0 / 30.0) / (d + w));
    rep.errors[std::string("period_over_overhead ") + c.name] = (1000.0 / 30.0) / (d + w);
  }
  std::error_code ec;
  fs::remove_all(scratch, ec);
  if (auto st = t.write_csv(out / "capture.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Capture overhead per frame (decode + atomic PNG write, one core)", "pixels per frame",
                "milliseconds (median)", "pixels", {"decode_ms", "write_ms", "overhead_ms"}, false, false, false};
  if (auto st = plot_png(t, spec, out / "capture.png"); !st) rep.warnings.push_back(st.error().message);
  rep.counts["repeats"] = repeats;
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// Calibration error vs number of views and seconds, on the board rig (known
// truth). Peer in the same run: the closed-form axis from per-view PnP.
int bench_calibrate(const fs::path& out) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.calibrate";
  const fs::path session = out / "board_session";
  std::error_code ec;
  fs::remove_all(session, ec);
  SynthOptions so;
  so.scene = "board";
  so.views = 48;
  auto synth = synth_session(so, session);
  if (!synth) return error(synth.error().message);
  auto truth = load_ground_truth(session);
  auto s = load_session(session);
  if (!truth || !s) return error("cannot read the board session back");
  const BoardSpec board = *BoardSpec::parse("chessboard:9x6:0.02");
  std::vector<AxisView> visible;
  for (const auto& f : s->frames) {
    auto d = detect_board(*load_color(*s, f), board);
    if (d && d->found) visible.push_back({f.table_angle_commanded_deg, std::move(*d), f.color});
  }
  const Eigen::Vector3d d_true = truth->axis_dir_camera;
  const Eigen::Vector3d p_true = truth->axis_point_camera - d_true * d_true.dot(truth->axis_point_camera);
  SweepTable t;
  t.columns = {"views", "fx_error_percent", "intrinsics_rms_px", "intrinsics_seconds", "axis_dir_error_deg",
               "axis_point_error_mm", "pnp_axis_dir_error_deg", "pnp_axis_point_error_mm", "axis_seconds"};
  for (size_t n : {3, 4, 6, 8, 12, 16, 100}) {
    if (n > visible.size()) n = visible.size();
    std::vector<AxisView> use;
    for (size_t k = 0; k < n; ++k) use.push_back(visible[k * visible.size() / n]);
    std::vector<BoardDetection> dets;
    for (const auto& v : use) dets.push_back(v.detection);
    IntrinsicsOptions io;
    io.board = board;
    io.fix_k3 = true;
    Stopwatch si;
    auto in = calibrate_intrinsics(dets, {}, truth->color.width, truth->color.height, io);
    const double ts = si.seconds();
    Stopwatch sa;
    auto ax = calibrate_turntable_axis(use, truth->color);
    const double ta = sa.seconds();
    if (!in || !ax) continue;
    auto ang = [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
      return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180 / M_PI;
    };
    t.rows.push_back({double(n), 100 * std::abs(in->calibration.intrinsics.fx / truth->color.fx - 1),
                      in->calibration.rms_px, ts, ang(ax->axis.direction_camera, d_true),
                      1000 * (ax->axis.point_camera - p_true).norm(), ang(ax->initial_direction, d_true),
                      1000 * (ax->initial_point - p_true).norm(), ta});
    std::fprintf(stderr, "%2zu views: fx err %.3f %% (%.3f s); axis %.4f deg / %.3f mm (PnP start %.4f deg / %.3f mm), %.3f s\n",
                 n, t.rows.back()[1], ts, t.rows.back()[4], t.rows.back()[5], t.rows.back()[6], t.rows.back()[7], ta);
    if (n == visible.size()) break;
  }
  fs::remove_all(session, ec);
  if (auto st = t.write_csv(out / "calibrate.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Calibration error vs views (board rig, known truth)", "views", "error", "views",
                {"fx_error_percent", "axis_dir_error_deg", "pnp_axis_dir_error_deg", "axis_point_error_mm"},
                false, false, true};
  if (auto st = plot_png(t, spec, out / "calibrate.png"); !st) rep.warnings.push_back(st.error().message);
  PlotSpec time_spec{"Axis error vs seconds (board rig)", "seconds (Ceres axis fit)", "error",
                     "axis_seconds", {"axis_dir_error_deg", "axis_point_error_mm"}, false, false, true};
  if (auto st = plot_png(t, time_spec, out / "calibrate_time.png"); !st) rep.warnings.push_back(st.error().message);
  PlotSpec fx_spec{"Focal length error vs seconds (board rig, turntable views)", "seconds (OpenCV intrinsics)",
                   "fx error (%)", "intrinsics_seconds", {"fx_error_percent"}, false, false, true};
  if (auto st = plot_png(t, fx_spec, out / "calibrate_fx_time.png"); !st) rep.warnings.push_back(st.error().message);
  rep.counts["visible_views"] = double(visible.size());
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// Registration error against run time on the real Stanford ring scans from
// poses perturbed by 5 deg / 5 mm: ours (one Ceres problem over all views,
// each coarse-to-fine round a point) against PCL's point-to-plane ICP chained
// view to view (each iteration cap a point), in the same run.
int bench_register(const fs::path& out, int seeds) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.register";
  const fs::path conf = data_dir() / "stanford_bunny" / "bun.conf";
  auto in = load_stanford_views(conf, {});
  if (!in) return error(in.error().message);
  // Ours runs on all ten scans (the top, chin and ear scans tie the ring
  // together) and on the six ring scans alone; the peer, PCL's ICP chained
  // view to view, on the ring. Errors are over the ring scans, against bun000.
  const std::vector<std::string> ring_names = {"bun000.ply", "bun045.ply", "bun090.ply",
                                               "bun180.ply", "bun270.ply", "bun315.ply"};
  std::vector<int> ring_index;  // into in->views, in ring order
  for (const auto& name : ring_names)
    for (size_t i = 0; i < in->views.size(); ++i)
      if (in->views[i].name == name) ring_index.push_back(static_cast<int>(i));
  if (ring_index.size() != ring_names.size()) return error(conf.string() + ": the six ring scans are not all there");
  const int fixed = ring_index.front();
  const Eigen::Vector3d centre = points_centre(in->views, in->given);
  auto ring_of = [&](const std::vector<Eigen::Isometry3d>& all) {
    std::vector<Eigen::Isometry3d> r;
    for (int i : ring_index) r.push_back(all[static_cast<size_t>(i)]);
    return r;
  };
  std::vector<RegistrationView> ring_views;
  for (int i : ring_index) ring_views.push_back(in->views[static_cast<size_t>(i)]);
  const std::vector<Eigen::Isometry3d> ring_truth = ring_of(in->given);
  // Max errors over the ring scans, poses in ring order, bun000 first.
  auto ring_error = [&](const std::vector<Eigen::Isometry3d>& ring_poses) {
    return pose_error(ring_poses, ring_truth, centre, 0);
  };
  SweepTable t;
  t.columns = {"seed", "iterations", "seconds", "max_rot_err_deg", "max_trans_err_mm", "rms_mm"};
  auto rms_at = [&](const std::vector<Eigen::Isometry3d>& poses, double voxel) {
    auto r = fit_rms(ring_views, poses, voxel);
    return r ? *r : -1.0;
  };
  double ours_worst = 0, ours_all_views_worst = 0, ring_only_worst = 0, icp_best = 1e9, icp_worst = 0;
  double ours_seconds = 0, ring_only_seconds = 0, icp_seconds = 0;
  for (int seed = 1; seed <= seeds; ++seed) {
    const auto start = perturb_poses(in->given, 5, 0.005, static_cast<uint64_t>(seed), centre, fixed);
    double final_voxel = 0.0005;
    auto run_ours = [&](std::vector<RegistrationView> vs, const std::vector<Eigen::Isometry3d>& init, int fixed_view,
                        bool all_ten) -> Result<RegistrationResult> {
      for (size_t i = 0; i < vs.size(); ++i) vs[i].initial = init[i];
      RegistrationOptions o;
      o.progress = false;
      o.fixed_view = fixed_view;
      const std::string label = std::string(all_ten ? "ours (Ceres, all ten scans)" : "ours (Ceres, ring scans only)") +
                                ", seed " + std::to_string(seed);
      o.on_round = [&](const RegistrationRound& r) {
        const PoseError e = ring_error(all_ten ? ring_of(r.poses) : r.poses);
        t.row_labels.push_back(label);
        t.rows.push_back({double(seed), double(r.solver_iterations), r.seconds, e.max_rotation_deg,
                          1e3 * e.max_translation_m, 1e3 * r.rms_m});
        final_voxel = r.voxel_m;
      };
      return register_views(vs, o);
    };
    auto r = run_ours(in->views, start, fixed, true);
    if (!r) return error(r.error().message);
    const PoseError eo = ring_error(ring_of(r->poses));
    const PoseError ea = pose_error(r->poses, in->given, centre, fixed);
    ours_worst = std::max(ours_worst, eo.max_rotation_deg);
    ours_all_views_worst = std::max(ours_all_views_worst, ea.max_rotation_deg);
    ours_seconds += r->seconds;
    auto rr = run_ours(ring_views, ring_of(start), 0, false);
    if (!rr) return error(rr.error().message);
    const PoseError er = ring_error(rr->poses);
    ring_only_worst = std::max(ring_only_worst, er.max_rotation_deg);
    ring_only_seconds += rr->seconds;
    double icp80 = 0;
    for (int iters : {1, 2, 5, 10, 20, 40, 80}) {
      IcpPeerOptions io;
      io.max_iterations = iters;
      io.voxel_m = final_voxel;
      auto vs = ring_views;
      for (size_t i = 0; i < vs.size(); ++i) vs[i].initial = start[static_cast<size_t>(ring_index[i])];
      Stopwatch sw;
      const auto poses = chain_icp(vs, io);
      const double secs = sw.seconds();
      const PoseError e = ring_error(poses);
      t.row_labels.push_back("PCL ICP chained (ring), seed " + std::to_string(seed));
      t.rows.push_back({double(seed), double(iters), secs, e.max_rotation_deg, 1e3 * e.max_translation_m,
                        1e3 * rms_at(poses, final_voxel)});
      if (iters == 80) icp80 = e.max_rotation_deg, icp_seconds += secs;
    }
    icp_best = std::min(icp_best, icp80), icp_worst = std::max(icp_worst, icp80);
    std::fprintf(stderr,
                 "seed %d: ours (all ten) ring %.3f deg, every scan %.3f deg in %.1f s; ours (ring only) %.3f deg in %.1f s; "
                 "chained ICP (80 iterations) %.3f deg\n",
                 seed, eo.max_rotation_deg, ea.max_rotation_deg, r->seconds, er.max_rotation_deg, rr->seconds, icp80);
  }
  if (auto st = t.write_csv(out / "register.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Registration of the Stanford bunny from 5 deg / 5 mm: ring error against run time", "seconds",
                "max rotation error of the ring scans vs bun.conf (deg)", "seconds", {"max_rot_err_deg"}, true, false, true};
  if (auto st = plot_png(t, spec, out / "register.png"); !st) rep.warnings.push_back(st.error().message);
  PlotSpec rms{"Registration: RMS point-to-plane against iterations", "iterations", "RMS (mm)", "iterations",
               {"rms_mm"}, true, false, true};
  if (auto st = plot_png(t, rms, out / "register_rms.png"); !st) rep.warnings.push_back(st.error().message);
  // Worst over the seeds: a registration is judged by its bad starts.
  rep.errors["ours_worst_ring_rotation_deg"] = ours_worst;
  rep.errors["ours_worst_any_scan_rotation_deg"] = ours_all_views_worst;
  rep.errors["ours_ring_only_worst_rotation_deg"] = ring_only_worst;
  rep.errors["icp_chain_best_ring_rotation_deg"] = icp_best;
  rep.errors["icp_chain_worst_ring_rotation_deg"] = icp_worst;
  rep.counts["ours_mean_seconds"] = ours_seconds / seeds;
  rep.counts["ours_ring_only_mean_seconds"] = ring_only_seconds / seeds;
  rep.counts["icp_chain_80_mean_seconds"] = icp_seconds / seeds;
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// Reconstruction error against build time on the rig (known surface), over
// the facet size w; the peer in the same run is Open3D's ScalableTSDFVolume +
// marching cubes on the same depth frames, poses and voxel size
// (scripts/open3d_tsdf_peer.py, python3-open3d).
int bench_reconstruct(const fs::path& out, const std::string& scene_in) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.reconstruct";
  std::error_code ec;
  fs::create_directories(out, ec);
  const std::string scene = scene_in == "blob" && fs::exists(data_dir() / "stanford_bunny" / "bun_zipper.ply") ? "bunny" : scene_in;
  const fs::path session = out / "session";
  fs::remove_all(session, ec);
  SynthOptions so;
  so.scene = scene;
  so.views = 24;
  so.seed = 3;
  if (auto made = synth_session(so, session); !made) return error(made.error().message);
  auto truth = load_ground_truth(session);
  if (!truth) return error(truth.error().message);
  auto mesh = read_ply_mesh(session / "ground_truth" / "geometry.ply");
  if (!mesh) return error(mesh.error().message);
  auto s = load_session(session);
  if (!s) return error(s.error().message);
  const fs::path peer_script = fs::path(build_source_dir()) / "scripts" / "open3d_tsdf_peer.py";
  // Debian's python3-open3d lives in the system interpreter (not a pyenv or venv one).
  const std::string python = fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : "python3";
  const bool have_peer = std::system((python + " -c 'import open3d' >/dev/null 2>&1").c_str()) == 0;
  if (!have_peer) rep.warnings.push_back("python3-open3d is not installed: the Open3D peer is left out (scripts/setup installs it)");

  SweepTable t;
  t.columns = {"voxel_mm", "seconds", "fusion_seconds", "median_mm", "p99_mm", "within_w", "elements"};
  std::vector<double> ratios, fusion_ratios;
  // Each side's median of kRuns runs: on a shared machine one run's time
  // swings by 15 % (the ratio more).
  constexpr int kRuns = 3;
  rep.params["runs_per_point"] = double(kRuns);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  for (double w : {0.0015, 0.002, 0.003, 0.004, 0.006}) {
    const SurfaceDistance distance_to_truth(*mesh, w / 5);
    ReconstructJob job;
    job.session = session;
    job.out = out / fmt::format("ours_{:.1f}mm", 1e3 * w);
    job.voxel_m = w;
    job.geometry = Geometry::depth;
    job.per_region = false;
    job.textures = false;
    Result<ReconstructSummary> r;
    std::vector<double> ours_runs, ours_fusion_runs;
    for (int k = 0; k < kRuns; ++k) {
      r = run_reconstruct_job(job);
      if (!r) return error(r.error().message);
      ours_runs.push_back(r->seconds), ours_fusion_runs.push_back(r->seconds_fusion);
    }
    const double ours_s = median(ours_runs), ours_fusion = median(ours_fusion_runs);
    t.row_labels.push_back("ours (OpenVDB fusion + facets + octree)");
    if (!r->truth) return error("bench reconstruct: the rig session has no ground truth");
    t.rows.push_back({1e3 * w, ours_s, ours_fusion, 1e3 * r->truth->all.median_m, 1e3 * r->truth->all.p99_m,
                      r->truth->all.within_size, double(r->facets.facets)});
    std::fprintf(stderr, "w %.1f mm: ours %.2f s (fusion %.2f s), median %.3f mm, within w %.4f, %g facets\n", 1e3 * w, ours_s,
                 ours_fusion, t.rows.back()[3], t.rows.back()[5], t.rows.back()[6]);
    // The patch mesh's vertices (interpolated crossings), comparable with marching cubes' vertices.
    if (auto patches = read_ply_mesh(job.out / "patches.ply")) {
      std::vector<FacetRecord> pv;
      for (const auto& v : patches->vertices) pv.push_back({{v.x(), v.y(), v.z()}, float(w), {0, 0, 0}, 0, 0, 0});
      const SurfaceError e = distance_to_truth.error(pv);
      t.row_labels.push_back("ours (octree patch mesh vertices)");
      t.rows.push_back({1e3 * w, ours_s, ours_fusion, 1e3 * e.median_m, 1e3 * e.p99_m, e.within_size, double(patches->faces.size())});
    }
    if (!have_peer) continue;
    nlohmann::json pj = {{"voxel", w}, {"trunc", 4 * w}, {"depth_scale", 1.0 / s->depth->unit_m}, {"depth_trunc", 5.0},
                         {"out", (out / fmt::format("open3d_{:.1f}mm.xyz", 1e3 * w)).string()}};
    for (size_t i = 0; i < s->frames.size(); ++i) {
      const Eigen::Matrix4d cfw = (truth->world_from_camera[i] * truth->color_from_depth).inverse().matrix();
      const Eigen::Matrix4d row = cfw.transpose();  // Eigen is column-major; the job is row-major
      const std::vector<double> m(row.data(), row.data() + 16);
      const Intrinsics& K = truth->depth;
      pj["frames"].push_back({{"depth", s->path_of(s->frames[i].depth).string()}, {"width", K.width}, {"height", K.height},
                              {"fx", K.fx}, {"fy", K.fy}, {"cx", K.cx}, {"cy", K.cy}, {"camera_from_world", m}});
    }
    const fs::path job_file = out / "open3d_job.json";
    if (auto st = write_file_atomic(job_file, pj.dump()); !st) return error(st.error().message);
    const std::string cmd = python + " " + sh_quote(peer_script.string()) + " " + sh_quote(job_file.string());
    nlohmann::json res;
    std::vector<double> peer_runs, peer_fusion_runs;
    for (int k = 0; k < kRuns; ++k) {
      const ShellRun peer = run_shell(cmd);
      if (peer.code != 0) return error("the Open3D peer failed (exit " + std::to_string(peer.code) + "): " + cmd);
      const std::string& line = peer.output;
      res = nlohmann::json::parse(line, nullptr, false);
      if (res.is_discarded() || !res.contains("seconds") || !res.contains("seconds_integrate"))
        return error("the Open3D peer printed no result: " + line);
      peer_runs.push_back(res["seconds"].get<double>()), peer_fusion_runs.push_back(res["seconds_integrate"].get<double>());
    }
    std::vector<FacetRecord> verts;
    {
      const std::string xyz_path = pj["out"].get<std::string>();
      FILE* xyz = std::fopen(xyz_path.c_str(), "r");
      if (!xyz) return error("the Open3D peer wrote no vertices: " + xyz_path);
      float x, y, z;
      while (std::fscanf(xyz, "%f %f %f", &x, &y, &z) == 3) verts.push_back({{x, y, z}, float(w), {0, 0, 0}, 0, 0, 0});
      std::fclose(xyz);
    }
    const SurfaceError pe = distance_to_truth.error(verts);
    const double peer_s = median(peer_runs), peer_fusion = median(peer_fusion_runs);
    t.row_labels.push_back("Open3D " + res["open3d"].get<std::string>() + " ScalableTSDF + marching cubes");
    t.rows.push_back({1e3 * w, peer_s, peer_fusion, 1e3 * pe.median_m, 1e3 * pe.p99_m, pe.within_size,
                      res["triangles"].get<double>()});
    ratios.push_back(ours_s / peer_s);
    fusion_ratios.push_back(ours_fusion / peer_fusion);
    std::fprintf(stderr, "w %.1f mm: Open3D %.2f s (integrate %.2f s), median %.3f mm, within w %.4f; time ratio ours/Open3D %.2f\n",
                 1e3 * w, peer_s, peer_fusion, t.rows.back()[3], t.rows.back()[5], ratios.back());
  }
  if (auto st = t.write_csv(out / "reconstruct.csv"); !st) return error(st.error().message);
  PlotSpec err{"Surface error vs facet size (rig " + scene + ", known surface)", "voxel / facet size w (mm)",
               "median distance to the true surface (mm)", "voxel_mm", {"median_mm"}, true, false, false};
  if (auto st = plot_png(t, err, out / "reconstruct_error.png"); !st) rep.warnings.push_back(st.error().message);
  PlotSpec secs{"Build seconds vs facet size (session files to geometry, median of 3 runs)", "voxel / facet size w (mm)", "seconds",
                "voxel_mm", {"seconds"}, true, false, true};
  if (auto st = plot_png(t, secs, out / "reconstruct_seconds.png"); !st) rep.warnings.push_back(st.error().message);
  PlotSpec evt{"Surface error against build time", "seconds", "median distance (mm)", "seconds", {"median_mm"}, true, true, true};
  if (auto st = plot_png(t, evt, out / "reconstruct_error_time.png"); !st) rep.warnings.push_back(st.error().message);
  // The error bound measured: the auto model, views turned away from every
  // camera by alpha, texels drawn on the billboards that pass the depth clip.
  {
    ReconstructJob job;
    job.session = session;
    job.out = out / "ours_auto";
    job.textures = false;
    auto r = run_reconstruct_job(job);
    if (!r) return error(r.error().message);
    auto model = load_model(job.out);
    if (!model) return error(model.error().message);
    SweepTable te;
    te.columns = {"angle_deg", "median_px", "p99_px", "max_px", "bound_ratio_max", "predicted_px"};
    const double w_coarse = r->voxel.coarse_m, z = r->near_distance_m;
    const double R = r->view_distance_m;
    const double f = model->cameras.front().intrinsics.fx;
    for (double a : {1.0, 2.5, 5.0, 7.5, 10.0, 15.0}) {
      auto e = measure_texel_error(*model, session, a);
      if (!e) return error(e.error().message);
      // The bound on the near side of the object (see reconstruct_job.cpp).
      const double alpha_near = std::asin(std::min(1.0, R * std::sin(a * std::numbers::pi / 180) / z));
      const double predicted = f * texel_error_bound(w_coarse, alpha_near) / z;
      te.row_labels.push_back("measured");
      te.rows.push_back({a, e->median_px, e->p99_px, e->max_px, e->max_ratio, predicted});
      std::fprintf(stderr, "alpha %.1f deg: texel error median %.3f px, p99 %.3f px, max %.3f px; bound for 2w0 facets on the near side %.3f px; "
                   "largest e / bound at the texel %.3f\n", a, e->median_px, e->p99_px, e->max_px, predicted, e->max_ratio);
      if (a == 7.5) rep.errors["texel_error_p99_px_at_half_gap"] = e->p99_px, rep.errors["texel_error_bound_ratio_max"] = e->max_ratio;
    }
    if (auto st = te.write_csv(out / "texel_error.csv"); !st) return error(st.error().message);
    PlotSpec tp{"Texel displacement on screen vs angle to the camera (auto facets, rig)", "angle between view and camera (deg)",
                "pixels", "angle_deg", {"median_px", "p99_px", "max_px", "predicted_px"}, false, false, false};
    if (auto st = plot_png(te, tp, out / "texel_error.png"); !st) rep.warnings.push_back(st.error().message);
  }
  if (!ratios.empty()) {
    rep.errors["time_ratio_ours_over_open3d_median"] = median(ratios);
    rep.errors["fusion_time_ratio_ours_over_open3d_median"] = median(fusion_ratios);
  }
  rep.params["scene"] = scene;
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// PSNR at held-out rig views against frame milliseconds at 1280x720, per
// drawing setting: blended cameras k, depth clipping, texel refinement, the
// adaptive clip, and the textured meshes in the same run.
int bench_render(const fs::path& out, const std::string& scene_in) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.render";
  std::error_code ec;
  fs::create_directories(out, ec);
  const std::vector<std::string> scenes =
      scene_in == "blob" ? std::vector<std::string>{"bunny", "fuzzy"} : std::vector<std::string>{scene_in};
  const std::vector<int> held{3, 11, 19};
  struct Setting {
    std::string label;
    DrawOptions draw;
  };
  std::vector<Setting> settings;
  // The reference settings blend every camera of the best k (min weight 0).
  auto plain = [] {
    DrawOptions d;
    d.selection.min_weight = 0;
    return d;
  };
  for (int k = 1; k <= 4; ++k) {
    Setting s{fmt::format("billboards k={}", k), plain()};
    s.draw.selection.cameras = k;
    settings.push_back(s);
  }
  {
    Setting s{"billboards k=3, no depth clipping", plain()};
    s.draw.depth_clip = false;
    settings.push_back(s);
    s = {"billboards k=3, no refinement", plain()};
    s.draw.refine_steps = 0;
    settings.push_back(s);
    s = {"billboards k=3, fixed clip (no widening)", plain()};
    s.draw.pixel_error = 0;
    settings.push_back(s);
    s = {"billboards k=3, no culling", plain()};
    s.draw.selection.frustum_cull = s.draw.selection.backface_cull = false;
    settings.push_back(s);
    s = {"patch mesh k=3", plain()};
    s.draw.geometry = DrawOptions::Geometry::kMesh;
    settings.push_back(s);
    s = {"surface mesh k=3", plain()};
    s.draw.geometry = DrawOptions::Geometry::kSurface;
    settings.push_back(s);
  }
  // Level of detail, each against "billboards k=3" (no LOD) in the same run:
  // blended cameras below a share left out, and the octree LOD's thresholds
  // (T_s contour pixels, T_b luminance x pixels, T_e texel pixels).
  const std::string no_lod = "billboards k=3";
  std::vector<std::string> lod_labels;
  for (double mw : {0.05, 0.1, 0.2}) {
    Setting s{fmt::format("k=3, min weight {}", mw), plain()};
    s.draw.selection.min_weight = mw;
    settings.push_back(s);
    lod_labels.push_back(s.label);
  }
  struct LodSetting {
    double shape, luminance, texel, min_weight;
  };
  for (const LodSetting& l : {LodSetting{0.5, 1.5, 1, 0}, LodSetting{1, 3, 2, 0}, LodSetting{2, 5, 4, 0},
                              LodSetting{4, 10, 8, 0}, LodSetting{0.5, 1.5, 1, 0.1}, LodSetting{1, 3, 2, 0.1},
                              LodSetting{4, 10, 8, 0.1}}) {
    Setting s{fmt::format("octree LOD T_s={} T_b={} T_e={}{}", l.shape, l.luminance, l.texel,
                          l.min_weight > 0 ? fmt::format(", min weight {}", l.min_weight) : std::string()),
              plain()};
    s.draw.lod.enabled = true;
    s.draw.lod.shape_px = l.shape;
    s.draw.lod.luminance = l.luminance;
    s.draw.lod.texel_px = l.texel;
    s.draw.selection.min_weight = l.min_weight;
    settings.push_back(s);
    lod_labels.push_back(s.label);
  }
  // The patch mesh where the geometry is reliable, billboards elsewhere.
  for (double r : {0.2, 0.5, 0.8}) {
    Setting s{fmt::format("hybrid: patch mesh at reliability >= {}, billboards elsewhere", r), plain()};
    s.draw.mesh_reliability = r;
    settings.push_back(s);
    lod_labels.push_back(s.label);
  }
  // Eval names the hybrid's row "hybrid" (its "billboards" row is billboards everywhere).
  auto method = [](const DrawOptions& d) { return std::string(d.mesh_reliability > 0 ? "hybrid" : "billboards"); };
  SweepTable t;
  t.columns = {"frame_ms", "psnr_db", "ssim", "coverage", "facets_drawn"};
  for (const auto& scene : scenes) {
    const fs::path session = out / ("session_" + scene), model = out / ("model_" + scene);
    fs::remove_all(session, ec);
    SynthOptions so;
    so.scene = scene;
    so.views = 24;
    so.seed = 3;
    if (auto made = synth_session(so, session); !made) return error(made.error().message);
    ReconstructJob job;
    job.session = session;
    job.out = model;
    job.holdout = held;
    auto built = run_reconstruct_job(job);
    if (!built) return error(built.error().message);
    rep.counts["facets_" + scene] = double(built->facets.facets);
    // The model's size in base voxels along its longest side (the issue's "128^3-voxel model").
    const auto loaded = load_model(model);
    const bool sized = loaded && loaded->voxel_size_m > 0 && !loaded->bounds.isEmpty();
    if (sized) {
      const double cells = loaded->bounds.sizes().maxCoeff() / loaded->voxel_size_m;
      rep.counts["voxels_per_side_" + scene] = std::round(cells);
      std::fprintf(stderr, "%s: %zu facets, %.0f base voxels along the longest side\n", scene.c_str(), loaded->facets.size(), cells);
    }
    // Held-out PSNR per setting, then every setting's frame time on one
    // loaded model, interleaved frame by frame (time_orbit).
    std::vector<const Setting*> ok;
    std::vector<EvalSummary> evals;
    for (const auto& setting : settings) {
      EvalJob e;
      e.model = model;
      e.source.session = session;
      e.frames = held;
      e.out = out / ("eval_" + scene);
      e.draw = setting.draw;
      e.baselines = false;
      auto ev = run_eval_job(e);
      if (!ev) {
        rep.warnings.push_back(scene + ", " + setting.label + ": " + ev.error().message);
        continue;
      }
      ok.push_back(&setting);
      evals.push_back(std::move(*ev));
    }
    std::vector<DrawOptions> draws;
    for (const Setting* s : ok) draws.push_back(s->draw);
    auto timing = time_orbit(model, draws, 1280, 720, 12);
    if (!timing) return error(timing.error().message);
    size_t base = ok.size();
    for (size_t k = 0; k < ok.size(); ++k) {
      const Setting& setting = *ok[k];
      const FrameTiming& ft = (*timing)[k];
      if (setting.label == no_lod) base = k;
      rep.params["renderer"] = ft.renderer;
      const EvalMethodFigures& ev = *evals[k].method(method(setting.draw));
      const double p = ev.psnr_db;
      t.row_labels.push_back(scene + ": " + setting.label);
      t.rows.push_back({ft.median_ms, p, ev.ssim, ev.coverage, ft.facets_drawn_mean});
      rep.errors[fmt::format("psnr_db_{}_{}", scene, setting.label)] = p;
      rep.counts[fmt::format("frame_ms_{}_{}", scene, setting.label)] = ft.median_ms;
      std::fprintf(stderr, "%s, %s: held-out PSNR %.2f dB, %.1f ms per 1280x720 frame\n", scene.c_str(), setting.label.c_str(), p,
                   ft.median_ms);
    }
    // LOD against no LOD: the median over orbit frames of the paired time
    // ratio, the PSNR change, and whether it cuts time at equal PSNR (within
    // 0.5 dB).
    if (base == ok.size()) continue;
    const double base_db = evals[base].method("billboards")->psnr_db;
    for (size_t k = 0; k < ok.size(); ++k) {
      const std::string& label = ok[k]->label;
      if (std::find(lod_labels.begin(), lod_labels.end(), label) == lod_labels.end()) continue;
      std::vector<double> ratios;
      for (size_t f = 0; f < (*timing)[k].frame_ms.size(); ++f)
        ratios.push_back((*timing)[k].frame_ms[f] / (*timing)[base].frame_ms[f]);
      const double ratio = median(ratios), delta = evals[k].method(method(ok[k]->draw))->psnr_db - base_db;
      rep.counts[fmt::format("lod_time_ratio_{}_{}", scene, label)] = ratio;
      rep.errors[fmt::format("lod_psnr_change_db_{}_{}", scene, label)] = delta;
      if (ratio < 1 && delta > -0.5) rep.counts[fmt::format("lod_faster_at_equal_psnr_{}_{}", scene, label)] = 1;
      std::fprintf(stderr, "%s, %s against %s: time x%.3f (paired median), PSNR %+.2f dB\n", scene.c_str(), label.c_str(),
                   no_lod.c_str(), ratio, delta);
    }
    // The first scene again at 128 base voxels along the model's longest
    // side (a 128^3-voxel model): frame times of billboards, the coarsest
    // octree LOD and the hybrid, paired frame by frame.
    if (scene != scenes.front() || !sized) continue;
    ReconstructJob fine = job;
    fine.out = out / ("model_" + scene + "_128");
    fine.voxel_m = loaded->bounds.sizes().maxCoeff() / 128;
    auto fine_built = run_reconstruct_job(fine);
    if (!fine_built) return error(fine_built.error().message);
    const std::vector<std::string> fine_labels{no_lod, "octree LOD T_s=4 T_b=10 T_e=8, min weight 0.1",
                                               "hybrid: patch mesh at reliability >= 0.2, billboards elsewhere"};
    std::vector<DrawOptions> fine_draws;
    for (const auto& l : fine_labels)
      for (const auto& st : settings)
        if (st.label == l) fine_draws.push_back(st.draw);
    auto fine_timing = time_orbit(fine.out, fine_draws, 1280, 720, 12);
    if (!fine_timing) return error(fine_timing.error().message);
    rep.counts["facets_" + scene + "_128"] = double(fine_built->facets.facets);
    for (size_t k = 0; k < fine_draws.size(); ++k) {
      const auto& ft = (*fine_timing)[k];
      rep.counts[fmt::format("frame_ms_{}_128_{}", scene, fine_labels[k])] = ft.median_ms;
      std::vector<double> ratios;
      for (size_t f = 0; f < ft.frame_ms.size(); ++f) ratios.push_back(ft.frame_ms[f] / (*fine_timing)[0].frame_ms[f]);
      if (k > 0) rep.counts[fmt::format("lod_time_ratio_{}_128_{}", scene, fine_labels[k])] = median(ratios);
      std::fprintf(stderr, "%s at 128 voxels per side (%.0f facets), %s: %.1f ms per 1280x720 frame, x%.3f of %s (paired median)\n",
                   scene.c_str(), double(fine_built->facets.facets), fine_labels[k].c_str(), ft.median_ms, median(ratios),
                   no_lod.c_str());
    }
  }
  if (auto st = t.write_csv(out / "render.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Held-out PSNR against frame time (rig, 1280x720 frames)", "milliseconds per frame",
                "PSNR at held-out views (dB)", "frame_ms", {"psnr_db"}, true, false, false};
  if (auto st = plot_png(t, spec, out / "render.png"); !st) rep.warnings.push_back(st.error().message);
  rep.params["held_out_frames"] = std::string("3,11,19");
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// Mochizuki and Makino's table 2: the four scenes (A mirrors spread over every screen, B
// diffuse spread, C mirrors on the front screen only, D diffuse front only),
// full render against visual-field LOD with the gaze forward and down, on the
// three CAVE screens. Error: PSNR against the full render inside the central
// field (must be identical) and over every pixel. The peer is the full render
// in the same run, timings interleaved, medians of `repeats`.
int bench_raytrace(const fs::path& out, int repeats, int size) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.raytrace";
  std::error_code ec;
  fs::create_directories(out, ec);
  auto bunny = read_ply_mesh(data_dir() / "stanford_bunny" / "bun_zipper.ply");
  if (!bunny) return error("bench raytrace needs the Stanford bunny: " + bunny.error().message);
  const auto screens = cave_screens(size);
  const Eigen::Vector3d eye = cave_default_eye();
  const std::vector<std::pair<std::string, Eigen::Vector3d>> gazes{{"forward", {0, 0, -1}}, {"down", {0, -1, 0}}};
  SweepTable t;
  t.columns = {"time_ratio", "psnr_all_db", "full_s", "lod_s", "psnr_central_db", "central_frac", "outside_frac",
               "rays_lod", "rays_full", "bvh_build_s"};
  double spread_worst = 0, best = 1e9;
  for (char scene : {'A', 'B', 'C', 'D'}) {
    SeedSceneOptions so;
    so.scene = scene;
    auto s = seed_scene(*bunny, so);
    if (!s) return error(s.error().message);
    auto tracer = RayTracer::create(std::move(*s));
    if (!tracer) return error(tracer.error().message);
    const RayTracer& rt = **tracer;
    // One thread: on a shared 2-core machine the second core is the one other
    // work steals, and a ratio of two single-thread renders does not care.
    TraceOptions full;
    full.threads = 1;
    std::vector<TraceOptions> lod(gazes.size());
    for (size_t g = 0; g < gazes.size(); ++g) {
      lod[g].threads = 1;
      lod[g].field_lod = true;
      lod[g].gaze = *EyeFrame::look(gazes[g].second);
    }
    render_layout(rt, screens, eye, full);  // warm caches
    std::vector<double> full_s;
    std::vector<std::vector<double>> lod_s(gazes.size());
    LayoutRender ref;
    std::vector<LayoutRender> got(gazes.size());
    for (int r = 0; r < repeats; ++r) {
      ref = render_layout(rt, screens, eye, full);
      full_s.push_back(ref.seconds);
      for (size_t g = 0; g < gazes.size(); ++g) {
        got[g] = render_layout(rt, screens, eye, lod[g]);
        lod_s[g].push_back(got[g].seconds);
      }
    }
    const double tf = *std::min_element(full_s.begin(), full_s.end());
    for (size_t g = 0; g < gazes.size(); ++g) {
      // Best of `repeats` for both, interleaved: on a shared machine bursts of
      // other load only ever add time, so the minimum is the steadiest estimate
      // of what each render costs. The median paired ratio is reported beside it.
      std::vector<double> ratios;
      for (int r = 0; r < repeats; ++r) ratios.push_back(lod_s[g][r] / full_s[r]);
      const double tl = *std::min_element(lod_s[g].begin(), lod_s[g].end()), ratio = tl / tf;
      rep.errors[fmt::format("time_ratio_median_paired_{}_{}", scene, gazes[g].first)] = median(ratios);
      const double central = psnr_where(got[g], ref, 1.0, 1.0), all = psnr_where(got[g], ref, 0.0, 1.0);
      const auto& st = got[g].stats;
      const std::string label = fmt::format("{} {}", scene, gazes[g].first);
      t.row_labels.push_back(label);
      t.rows.push_back({ratio, std::isinf(all) ? 100.0 : all, tf, tl, std::isinf(central) ? 100.0 : central,
                        double(st.central) / double(st.pixels), double(st.outside_field) / double(st.pixels),
                        double(st.primary + st.secondary + st.shadow),
                        double(ref.stats.primary + ref.stats.secondary + ref.stats.shadow), rt.build_seconds()});
      const std::string key = fmt::format("{}_{}", scene, gazes[g].first);
      rep.errors["time_ratio_" + key] = ratio;
      rep.errors["psnr_all_pixels_db_" + key] = std::isinf(all) ? 100.0 : all;
      rep.errors["psnr_central_field_db_" + key] = std::isinf(central) ? 100.0 : central;
      rep.params["central_field_identical_" + key] = std::isinf(central);
      rep.skipped["pixels_outside_field_" + key] = double(st.outside_field);
      rep.skipped["branches_beyond_reflect_budget_" + key] = double(st.depth_cut);
      if (scene == 'A' || scene == 'B') spread_worst = std::max(spread_worst, ratio);
      best = std::min(best, ratio);
      std::fprintf(stderr, "scene %s: full %.4f s, LOD %.4f s (%.1f %%); central field %s; all pixels %.2f dB; rays %.0f vs %.0f\n",
                   label.c_str(), tf, tl, 100 * ratio,
                   std::isinf(central) ? "identical" : fmt::format("{:.2f} dB", central).c_str(), all,
                   double(st.primary + st.secondary + st.shadow), double(ref.stats.primary + ref.stats.secondary + ref.stats.shadow));
    }
    rep.counts[fmt::format("full_render_s_{}", scene)] = tf;
    rep.counts[fmt::format("bvh_build_s_{}", scene)] = rt.build_seconds();
    // What switching by rebuilding each frame (the paper's way) would add.
    rep.errors[fmt::format("rebuild_per_frame_over_full_{}", scene)] = rt.build_seconds() / tf;
  }
  rep.errors["time_ratio_best"] = best;
  rep.errors["time_ratio_spread_worst"] = spread_worst;
  if (auto st = t.write_csv(out / "raytrace.csv"); !st) return error(st.error().message);
  PlotSpec spec{fmt::format("Visual-field LOD: PSNR against the full render vs time ratio ({} CAVE screens of {}^2)", screens.size(), size),
                "LOD time / full render time", "PSNR over all pixels (dB; 100 = identical)", "time_ratio", {"psnr_all_db"}, true,
                false, false};
  if (auto st = plot_png(t, spec, out / "raytrace.png"); !st) rep.warnings.push_back(st.error().message);
  rep.params["screen_pixels"] = static_cast<double>(size);
  rep.params["repeats"] = static_cast<double>(repeats);
  rep.params["threads"] = 1.0;
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}


// Okumura's (2003) tables 3/4 as a sweep: weight threshold th and pyramid resolution
// (samples per lobe scale) and map size vs error against the brute-force lobe
// vs build seconds vs memory, on the panorama with a sun 10^4 times its sky;
// then the default setting on every bundled panorama. The peer is the brute
// force itself: its seconds per voxel, measured in the same run, times the
// voxels of the map is what the unaccelerated build would take.
int bench_envmap(const fs::path& out, int voxels) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.envmap";
  std::error_code ec;
  fs::create_directories(out, ec);
  const fs::path hdri = data_dir() / "hdri";
  struct Config {
    std::string panorama;
    int size;
    double threshold, samples_per_scale;
    int check;
    double levels = 256;
  };
  std::vector<Config> configs;
  const int few = std::max(200, voxels / 10);
  for (int size : {32, 64, 128, 256}) configs.push_back({"royal_esplanade_1k.hdr", size, 1e-3, 2, size == 128 ? voxels : few});
  for (double th : {1e-2, 1e-3, 1e-4})
    for (double r : {1.0, 2.0, 3.0})
      if (!(th == 1e-3 && r == 2)) configs.push_back({"royal_esplanade_1k.hdr", 128, th, r, few});
  // Fewer intensity levels: wider lobes per voxel spacing (smoother between
  // voxels), a duller sharpest lobe g(1).
  for (double levels : {16.0, 64.0}) configs.push_back({"royal_esplanade_1k.hdr", 128, 1e-3, 2, few, levels});
  for (const char* p : {"venice_sunset_1k.hdr", "pedestrian_overpass_1k.hdr", "spruit_sunrise_1k.hdr", "blouberg_sunrise_2_1k.hdr"})
    configs.push_back({p, 128, 1e-3, 2, few});
  SweepTable t;
  t.columns = {"build_s", "mean_display_error_x255", "max_display_error_x255", "mean_display_error_interpolated_x255",
               "max_relative_error", "size", "threshold", "samples_per_scale", "intensity_levels", "exponent_at_lambda_1", "samples_per_voxel", "memory_mb", "file_mb",
               "brute_force_build_s_estimate", "speedup_vs_brute_force", "checked_voxels"};
  std::map<std::string, Panorama> panoramas;
  for (const Config& c : configs) {
    if (!panoramas.count(c.panorama)) {
      std::vector<std::string> warnings;
      auto p = load_panorama(hdri / c.panorama, false, &warnings);
      if (!p) return error("bench envmap: " + p.error().message);
      panoramas.emplace(c.panorama, std::move(*p));
    }
    const Panorama& pano = panoramas.at(c.panorama);
    EnvmapOptions o;
    o.size = c.size;
    o.threshold = c.threshold;
    o.samples_per_scale = c.samples_per_scale;
    o.intensity_levels = c.levels;
    EnvmapStats st;
    auto map = build_envmap(pano, o, &st);
    if (!map) return error(map.error().message);
    const fs::path file = out / "envmap.exr";
    if (auto w = map->save(file, c.panorama); !w) return error(w.error().message);
    st.file_bytes = fs::file_size(file, ec);
    fs::remove(file, ec);
    auto acc = envmap_accuracy(*map, pano, c.check, 4, false, 1);
    auto between = envmap_accuracy(*map, pano, std::max(200, c.check / 5), 4, true, 2);
    if (!acc) return error(acc.error().message);
    if (!between) return error(between.error().message);
    // Brute force on every computed voxel, at the seconds per voxel measured here (all cores).
    const double brute = acc->reference_seconds / std::max<size_t>(1, acc->all.count) * static_cast<double>(st.voxels);
    const std::string label = fmt::format("{} s={} th={:g} R={:g} I={:g}", c.panorama.substr(0, c.panorama.find('_')),
                                          c.size, c.threshold, c.samples_per_scale, c.levels);
    t.row_labels.push_back(label);
    t.rows.push_back({st.seconds, 255 * acc->all.mean_display, 255 * acc->all.max_display, 255 * between->all.mean_display,
                      acc->all.max_relative, double(c.size), c.threshold, c.samples_per_scale, c.levels,
                      envmap_exponent(1, c.size, c.levels),
                      st.samples / std::max<size_t>(1, st.voxels), st.memory_bytes / 1e6, st.file_bytes / 1e6, brute,
                      brute / st.seconds, double(acc->all.count)});
    std::fprintf(stderr,
                 "%-40s build %6.2f s, error mean %.4f max %.3f grey levels (between voxels %.4f), %.0f samples/voxel, "
                 "%.0f MB, brute force ~%.0f s (%.0fx)\n",
                 label.c_str(), st.seconds, 255 * acc->all.mean_display, 255 * acc->all.max_display,
                 255 * between->all.mean_display, st.samples / std::max<size_t>(1, st.voxels), st.memory_bytes / 1e6, brute,
                 brute / st.seconds);
    if (c.size == 128 && c.threshold == 1e-3 && c.samples_per_scale == 2 && c.levels == 256) {
      const std::string key = c.panorama.substr(0, c.panorama.find('_'));
      rep.errors["mean_display_error_" + key] = acc->all.mean_display;
      rep.errors["max_display_error_" + key] = acc->all.max_display;
      rep.errors["mean_display_error_interpolated_" + key] = between->all.mean_display;
      rep.counts["build_seconds_" + key] = st.seconds;
      rep.counts["checked_voxels_" + key] = double(acc->all.count);
      rep.counts["brute_force_build_seconds_estimate_" + key] = brute;
      if (key == "royal")
        for (const auto& b : acc->bands) {
          const std::string band = fmt::format("lambda_{:.2f}_{:.2f}", b.lambda_lo, b.lambda_hi);
          rep.errors["mean_display_error_royal_" + band] = b.mean_display;
          rep.errors["max_display_error_royal_" + band] = b.max_display;
        }
      if (key == "royal")
        for (const auto& b : between->bands)
          rep.errors[fmt::format("mean_display_error_interpolated_royal_lambda_{:.2f}_{:.2f}", b.lambda_lo, b.lambda_hi)] =
              b.mean_display;
    }
  }
  // Rendering: a glossy sphere with per-pixel roughness, GL from the map
  // against the ray tracer's exact lobe, on two panoramas.
  for (const char* p : {"venice_sunset_1k.hdr", "royal_esplanade_1k.hdr"}) {
    const std::string key = std::string(p).substr(0, std::string(p).find('_'));
    auto pano = std::make_shared<const Panorama>(panoramas.at(p));
    auto map = build_envmap(*pano, EnvmapOptions{});
    if (!map) return error(map.error().message);
    auto cmp = compare_glossy_sphere(pano, std::make_shared<const EnvironmentMap>(std::move(*map)), roughness_ramps(3), 160);
    if (!cmp) return error(cmp.error().message);
    rep.errors["glossy_sphere_mean_error_grey_levels_" + key] = cmp->mean_error;
    rep.errors["glossy_sphere_max_error_grey_levels_" + key] = cmp->max_error;
    rep.errors["glossy_sphere_grazing_mean_error_grey_levels_" + key] = cmp->grazing_mean_error;
    rep.errors["glossy_sphere_grazing_max_error_grey_levels_" + key] = cmp->grazing_max_error;
    rep.counts["glossy_sphere_pixels_" + key] = double(cmp->pixels);
    rep.counts["glossy_sphere_grazing_pixels_" + key] = double(cmp->grazing_pixels);
    rep.counts["glossy_sphere_gl_frame_ms_" + key] = cmp->gl_frame_ms;
    rep.counts["glossy_sphere_ray_traced_seconds_" + key] = cmp->trace_seconds;
    ImageU8 diff(cmp->gl.width, cmp->gl.height, 3);
    for (size_t i = 0; i < diff.data.size(); ++i)
      diff.data[i] = static_cast<uint8_t>(std::min(255, 8 * std::abs(int(cmp->gl.data[i]) - int(cmp->traced.data[i]))));
    ImageU8 strip(cmp->gl.width * 3, cmp->gl.height, 3);
    for (int y = 0; y < diff.height; ++y)
      for (int x = 0; x < diff.width; ++x)
        for (int c = 0; c < 3; ++c) {
          strip.at(x, y, c) = cmp->gl.at(x, y, c);
          strip.at(x + diff.width, y, c) = cmp->traced.at(x, y, c);
          strip.at(x + 2 * diff.width, y, c) = diff.at(x, y, c);
        }
    if (auto w = write_image(out / ("glossy_sphere_" + key + ".png"), strip); !w) return error(w.error().message);
    std::fprintf(stderr, "glossy sphere (%s, 160^2, roughness ramps per pixel): GL %.1f ms vs ray traced %.1f s; error mean %.2f "
                 "max %.0f grey levels, grazing (%zu px) mean %.2f max %.0f\n", key.c_str(), cmp->gl_frame_ms, cmp->trace_seconds,
                 cmp->mean_error, cmp->max_error, cmp->grazing_pixels, cmp->grazing_mean_error, cmp->grazing_max_error);
  }
  if (auto st = t.write_csv(out / "envmap.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Environment map: mean error against brute-force Phong vs build seconds (2 cores)", "build seconds",
                "mean error (grey levels of 255)", "build_s", {"mean_display_error_x255"}, true, true, true};
  if (auto st = plot_png(t, spec, out / "envmap.png"); !st) rep.warnings.push_back(st.error().message);
  rep.params["checked_voxels_default"] = static_cast<double>(voxels);
  rep.params["threads"] = static_cast<double>(worker_count(0));
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

// Tsutsumi's (2010) material LOD comparison: parallax occlusion mapping everywhere
// against the per-pixel switch by eq. 4.1, on a flat board and on a roof
// model, for the thesis's (R, D) conditions and a flat material (whose detailed
// method is bump mapping). Frame time best of N interleaved; PSNR against the
// detailed method over all pixels and inside the switch band |V - T| <= blend.
int bench_material(const fs::path& out, int repeats) {
  Stopwatch total;
  Report rep;
  rep.stage = "bench.material";
  std::error_code ec;
  fs::create_directories(out, ec);
  auto ctx = create_headless_context();
  if (!ctx) return error(ctx.error().message);
  const int W = 800, H = 500;
  auto fb = Framebuffer::create(W, H);
  if (!fb) return error(fb.error().message);
  struct Case {
    double R, D;
  };
  const std::vector<Case> cases{{200, 200}, {200, 600}, {200, 1000}, {600, 200}, {1000, 200}, {1000, 1000}, {200, 0}};
  SweepTable t;
  t.columns = {"time_ratio", "psnr_all_db", "psnr_band_db", "detailed_ms", "lod_ms", "threshold_T", "switch_distance_m",
               "detailed_fraction", "band_fraction", "R", "D"};
  MaterialDrawOptions base;
  for (const char* scene_name : {"board", "roof"}) {
    const MaterialScene scene = std::string(scene_name) == "board" ? material_board_scene(W, H) : material_roof_scene(W, H);
    for (const Case& c : cases) {
      const ReliefMaterial mat = brick_material(256, 2 + c.R / 1000 * 8, c.D / 1000 * 0.1);
      auto r = MaterialRenderer::create(scene.mesh, mat);
      if (!r) return error(r.error().message);
      MaterialDrawOptions detailed = base, lod = base, vmap = base;
      detailed.method = (*r)->flat() ? MaterialMethod::kBump : MaterialMethod::kParallax;
      lod.method = MaterialMethod::kLod;
      vmap.method = MaterialMethod::kDistanceMap;
      auto warm = (*r)->draw(scene.eye, scene.screen, *fb, detailed);
      if (!warm) return error(warm.error().message);
      std::vector<double> td, tl, ratios;
      ImageU8 img_d, img_l;
      for (int k = 0; k < repeats; ++k) {
        auto a = (*r)->draw(scene.eye, scene.screen, *fb, detailed);
        if (!a) return error(a.error().message);
        img_d = fb->read_rgb();
        auto b = (*r)->draw(scene.eye, scene.screen, *fb, lod);
        if (!b) return error(b.error().message);
        img_l = fb->read_rgb();
        td.push_back(a->frame_ms);
        tl.push_back(b->frame_ms);
        ratios.push_back(b->frame_ms / a->frame_ms);
      }
      if (auto v = (*r)->draw(scene.eye, scene.screen, *fb, vmap); !v) return error(v.error().message);
      const ImageU8 vimg = fb->read_rgb();
      const double T = (*r)->threshold();
      ImageU8 band(W, H, 1);
      size_t in_band = 0, detailed_px = 0, covered = 0;
      for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
          const bool sky = vimg.at(x, y, 2) != 0;  // the distance map's blue is 0 on surfaces
          const double V = 1000.0 * (vimg.at(x, y, 0) + vimg.at(x, y, 1) / 255.0) / 255.0;
          const bool b = !sky && std::abs(V - T) <= base.blend;
          band.at(x, y, 0) = b ? 255 : 0;
          in_band += b;
          if (!sky) {
            ++covered;
            if (V < T - base.blend) ++detailed_px;
          }
        }
      const double all = psnr(img_l, img_d).value_or(0);
      const double in = in_band ? psnr(img_l, img_d, &band).value_or(0) : INFINITY;
      const double best_d = *std::min_element(td.begin(), td.end()), best_l = *std::min_element(tl.begin(), tl.end());
      const std::string key = fmt::format("{}_R{:g}_D{:g}", scene_name, c.R, c.D);
      t.row_labels.push_back(key);
      t.rows.push_back({best_l / best_d, std::isinf(all) ? 100.0 : all, std::isinf(in) ? 100.0 : in, best_d, best_l, T,
                        base.near_m + T / 1000 * (base.far_m - base.near_m), double(detailed_px) / std::max<size_t>(1, covered),
                        double(in_band) / std::max<size_t>(1, covered), c.R, c.D});
      rep.errors["time_ratio_" + key] = best_l / best_d;
      rep.errors["time_ratio_median_paired_" + key] = median(ratios);
      rep.errors["psnr_all_db_" + key] = std::isinf(all) ? 100.0 : all;
      rep.errors["psnr_switch_band_db_" + key] = std::isinf(in) ? 100.0 : in;
      rep.counts["detailed_ms_" + key] = best_d;
      rep.counts["lod_ms_" + key] = best_l;
      rep.skipped["pixels_without_parallax_" + key] = double(covered - detailed_px);
      std::fprintf(stderr, "%-22s T %.0f (%.1f m): %s everywhere %.1f ms, LOD %.1f ms (%.0f %%); PSNR all %.1f dB, switch band %.1f dB\n",
                   key.c_str(), T, base.near_m + T / 1000 * (base.far_m - base.near_m), (*r)->flat() ? "bump" : "POM", best_d,
                   best_l, 100 * best_l / best_d, all, in);
      if (c.R == 200 && (c.D == 200 || c.D == 0)) {
        ImageU8 strip(W, 2 * H, 3);
        for (int y = 0; y < H; ++y)
          for (int x = 0; x < W; ++x)
            for (int ch = 0; ch < 3; ++ch) {
              strip.at(x, y, ch) = img_l.at(x, y, ch);
              const int d = std::min(255, 8 * std::abs(int(img_l.at(x, y, ch)) - int(img_d.at(x, y, ch))));
              strip.at(x, y + H, ch) = static_cast<uint8_t>(band.at(x, y, 0) ? std::max(d, ch == 2 ? 90 : 0) : d);
            }
        if (auto w = write_image(out / (key + ".png"), strip); !w) return error(w.error().message);
      }
    }
  }
  if (auto st = t.write_csv(out / "material.csv"); !st) return error(st.error().message);
  PlotSpec spec{"Material LOD: PSNR against the detailed method vs frame time ratio (llvmpipe, 800x500)",
                "LOD frame time / detailed frame time", "PSNR over all pixels (dB)", "time_ratio", {"psnr_all_db"}, true, false, false};
  if (auto st = plot_png(t, spec, out / "material.png"); !st) rep.warnings.push_back(st.error().message);
  rep.params["renderer"] = (*ctx)->describe();
  rep.params["repeats"] = double(repeats);
  rep.params["blend_v"] = base.blend;
  rep.seconds = total.seconds();
  return finish(rep, out / "report.json");
}

}  // namespace

int run(const BenchArgs& a) {
  const fs::path out = a.out;
  if (a.stage == "rig") return bench_rig(out, std::max(1, a.repeats), a.scene);
  if (a.stage == "capture") return bench_capture(out, std::max(5, a.repeats * 10));
  if (a.stage == "calibrate") return bench_calibrate(out);
  if (a.stage == "register") return bench_register(out, std::max(1, a.repeats));
  if (a.stage == "reconstruct") return bench_reconstruct(out, a.scene);
  if (a.stage == "render") return bench_render(out, a.scene);
  if (a.stage == "raytrace") return bench_raytrace(out, std::max(7, a.repeats), a.size);
  if (a.stage == "envmap") return bench_envmap(out, std::max(100, a.voxels));
  if (a.stage == "material") return bench_material(out, std::max(5, a.repeats));
  if (a.stage == "views") return bench_views(out, a.lego_views, a.fit, a.scenes);
  std::fprintf(stderr, "s2r bench %s: not yet available in this build (only 'rig', 'capture', 'calibrate', 'register', 'reconstruct', 'render', 'raytrace', 'envmap', 'material' and 'views')\n", a.stage.c_str());
  return 2;
}

}  // namespace s2r::cli
