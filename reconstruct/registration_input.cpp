#include "reconstruct/registration_input.h"

#include <mutex>
#include <numbers>
#include <random>

#include "core/camera_model.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/rgbd.h"
#include "reconstruct/frame_inputs.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

void add_stats(PrepStats& total, const PrepStats& s) {
  total.input += s.input;
  total.outliers += s.outliers;
  total.no_normal += s.no_normal;
  total.edge += s.edge;
  total.kept += s.kept;
}

// Pre-processes every scan (in parallel), keeping the first error.
Status prepare_all(std::vector<PointScan>& scans, const std::vector<PrepOptions>& prep, RegistrationInput& in) {
  const int n = static_cast<int>(scans.size());
  std::vector<Result<ViewCloud>> out(scans.size(), fail("not prepared"));
  std::vector<PrepStats> stats(scans.size());
  Progress progress("prepare views", scans.size());
  std::mutex mu;
  parallel_for(n, 0, [&](int i) {
    out[i] = prepare_view(scans[i], prep[i], &stats[i]);
    scans[i] = {};
    std::lock_guard lock(mu);
    progress.tick();
  });
  progress.done();
  for (int i = 0; i < n; ++i) {
    if (!out[i]) return std::unexpected(with_context(out[i].error(), "view " + in.views[i].name));
    in.views[i].cloud = std::move(*out[i]);
    add_stats(in.prep, stats[i]);
  }
  return {};
}

}  // namespace

Result<RegistrationInput> load_stanford_views(const fs::path& conf_path, const PrepOptions& prep) {
  auto conf = read_stanford_conf(conf_path);
  if (!conf) return std::unexpected(conf.error());
  RegistrationInput in;
  std::vector<PointScan> scans;
  for (const auto& s : conf->scans) {
    auto scan = read_ply_points(conf_path.parent_path() / s.file);
    if (!scan) return std::unexpected(scan.error());
    RegistrationView v;
    v.name = s.file;
    v.initial = s.world_from_scan;
    in.views.push_back(std::move(v));
    in.given.push_back(s.world_from_scan);
    in.frames.push_back(static_cast<int>(scans.size()));
    scans.push_back(std::move(*scan));
  }
  // The scanner looks at the object from +z of each scan's frame. Its laser
  // stripes curl near silhouettes: three cells of edge, not one, bring bun180
  // against bun000 from 0.30-0.32 deg off bun.conf to 0.22-0.29 deg over ten
  // perturbed starts (0.23-0.27 with 2000 correspondences per pair), and the
  // fit's RMS from 0.168 to 0.135 mm.
  PrepOptions p = prep;
  p.viewpoint = Eigen::Vector3f(0, 0, 1);
  p.edge_cells = std::max(p.edge_cells, 3);
  std::vector<PrepOptions> per(scans.size(), p);
  if (auto st = prepare_all(scans, per, in); !st) return std::unexpected(st.error());
  in.conf = std::move(*conf);
  return in;
}

Result<RegistrationInput> load_session_views(const Session& s, const Calibration* cal, const PrepOptions& prep) {
  RegistrationInput in;
  const bool use_axis = cal && cal->axis;
  // Angles measured from this very session's images take the place of the
  // reported ones.
  const bool measured_angles = use_axis && cal->has_measured_angles(s);
  if (use_axis && !cal->axis->frame_angles_deg.empty() && !measured_angles)
    in.notes.push_back("the calibration's measured frame angles belong to session '" + cal->axis->frames_session +
                       "' (" + std::to_string(cal->axis->frame_angles_deg.size()) + " frames), not this one: reported angles used");
  if (use_axis) {
    TurntablePrior tt;
    // World = the table frame at angle 0 = the colour camera frame at angle 0.
    tt.direction = cal->axis->direction_camera.normalized();
    tt.point = cal->axis->point_camera;
    in.turntable = tt;
    in.notes.push_back(measured_angles ? "initial poses: the table angles measured from the session's markers (s2r calibrate markers)"
                                       : "initial poses: reported table angles about the calibrated axis");
  } else {
    in.notes.push_back("initial poses: the session's given poses");
  }
  const DepthSensorModel sensor = resolve_depth_sensor(s, cal);
  const std::optional<Intrinsics>& depth_K = sensor.intrinsics;
  const Eigen::Isometry3d& color_from_depth = sensor.color_from_depth;
  const double unit = sensor.unit_m;
  std::vector<PointScan> scans;
  std::vector<PrepOptions> per;
  size_t off_table = 0;
  for (const auto& f : s.frames) {
    RegistrationView v;
    v.name = "frame_" + std::to_string(f.index) + (f.source.empty() ? "" : "_" + f.source);
    if (use_axis) {
      v.initial = cal->world_from_camera_at(cal->frame_angle_deg(s, size_t(&f - s.frames.data())), s.layout);
    } else if (f.world_from_camera) {
      v.initial = *f.world_from_camera;
    } else {
      return fail("frame " + std::to_string(f.index) +
                  ": no initial pose: give a calibration with a turntable axis (s2r calibrate axis)");
    }
    PrepOptions p = prep;
    PointScan scan;
    if (!f.depth.empty()) {
      if (!depth_K) return fail("session has depth frames but no depth sensor intrinsics");
      auto d = load_depth(s, f);
      if (!d) return std::unexpected(d.error());
      if (use_axis) off_table += mask_off_table(*d, unit, *depth_K, color_from_depth, *cal->axis);
      scan = depth_to_scan(*d, unit, *depth_K, color_from_depth);
      p.viewpoint = color_from_depth.translation().cast<float>();
    } else if (!f.points.empty()) {
      auto pts = read_ply_points(s.path_of(f.points));
      if (!pts) return std::unexpected(pts.error());
      scan = std::move(*pts);
    } else {
      in.notes.push_back("frame " + std::to_string(f.index) + " skipped: no depth or points");
      continue;
    }
    in.views.push_back(std::move(v));
    in.given.push_back(in.views.back().initial);
    in.frames.push_back(f.index);
    scans.push_back(std::move(scan));
    per.push_back(p);
  }
  if (off_table) in.notes.push_back(std::to_string(off_table) + " depth samples off the turntable (background) left out");
  if (in.views.size() < 2) return fail("session '" + s.root.string() + "' has fewer than two frames with depth or points");
  if (auto st = prepare_all(scans, per, in); !st) return std::unexpected(st.error());
  return in;
}

std::vector<Eigen::Isometry3d> perturb_poses(const std::vector<Eigen::Isometry3d>& poses, double deg, double m,
                                             uint64_t seed, const Eigen::Vector3d& centre, int fixed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  auto unit = [&] {
    Eigen::Vector3d v(g(rng), g(rng), g(rng));
    return v.normalized();
  };
  std::vector<Eigen::Isometry3d> out = poses;
  for (size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Vector3d axis = unit(), shift = unit();  // drawn for every view: stable per index
    if (static_cast<int>(i) == fixed) continue;
    Eigen::Isometry3d d = rotation_about_axis(axis, centre, deg * std::numbers::pi / 180);
    d.pretranslate(m * shift);
    out[i] = d * poses[i];
  }
  return out;
}

}  // namespace s2r
