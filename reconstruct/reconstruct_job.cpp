#include "reconstruct/reconstruct_job.h"

#include <algorithm>
#include <atomic>
#include <future>
#include <map>
#include <mutex>
#include <cmath>
#include <numbers>
#include <optional>
#include <set>
#include <sys/resource.h>

#include <spdlog/fmt/fmt.h>

#include "calibrate/calibration.h"
#include "capture/ground_truth.h"
#include "core/image_io.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/sweep.h"
#include "reconstruct/backdrop_plate.h"
#include "reconstruct/camera_depth.h"
#include "reconstruct/frame_inputs.h"
#include "reconstruct/fusion.h"
#include "reconstruct/microfacets.h"
#include "reconstruct/model.h"
#include "reconstruct/octree.h"
#include "reconstruct/photo_depth.h"
#include "reconstruct/poses.h"
#include "reconstruct/rig_eval.h"
#include "reconstruct/splat_composite.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

struct Timer {
  Report& rep;
  Stopwatch clock;
  double cpu0 = cpu_now();
  static double cpu_now() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
  }
  double lap(const std::string& step) {
    const double seconds = clock.seconds();
    rep.counts["seconds_" + step] = seconds;
    const double c = cpu_now();
    rep.counts["cpu_" + step] = c - cpu0;
    cpu0 = c;
    clock = Stopwatch();
    return seconds;
  }
};


// What the job reads: the session, its poses and calibration, the frames held
// out, and the depth sensor they are read with.
struct Inputs {
  Session s;
  FramePoses poses;
  std::optional<Calibration> cal;
  std::set<int> held;
  DepthSensorModel sensor;
  const Calibration* calibration() const { return cal ? &*cal : nullptr; }
};

// A frame the model is built from: a pose and a colour image, not held out.
struct View {
  int frame;
  Intrinsics K;
  Eigen::Isometry3d world_from_camera;
  ImageU8 color;
  ImageU16 depth;
  ImageU8 matte;  // the session's matte of the object, where it has one
};

// Where the object is, how far the cameras are and how far apart.
struct SceneExtent {
  Eigen::Vector3d centre;
  Eigen::AlignedBox3d box;
  std::optional<Eigen::AlignedBox3d> crop;  // object-centre sessions: fusion keeps to the box
  double view_distance = 0, near_distance = 0;
  CameraSpacing spacing;
  double delta = 0;  // the texel angle at the object's near side
  double focal = 0, pixel_m = 0;
};

// Where the geometry comes from, with the silhouettes when the hull is used.
struct GeometryPlan {
  Geometry mode = Geometry::automatic;
  std::vector<ImageU8> masks;
  bool uses_depth() const { return mode == Geometry::depth || mode == Geometry::both; }
  bool uses_hull() const { return mode == Geometry::hull || mode == Geometry::both; }
};

// The surface octree and its finest crack-free patch mesh (the textured-mesh
// baseline), built in a task of its own.
struct OctreePart {
  std::vector<OctreeRecord> records;
  int max_level = 0;
  std::map<std::string, double> counts;
  bool patch_mesh = false;
};

Result<Inputs> load_inputs(const ReconstructJob& job) {
  // Image headers are not probed here: the frames the job uses are decoded
  // by load_views and their sizes checked against the intrinsics then.
  auto session = load_session(job.session, {.check_images = false});
  if (!session) return std::unexpected(session.error());
  Inputs in{std::move(*session), {}, {}, {}, {}};
  auto poses = resolve_frame_poses(in.s, job.poses, job.calibration);
  if (!poses) return std::unexpected(poses.error());
  in.poses = std::move(*poses);
  if (!job.calibration.empty()) {
    auto c = load_calibration(job.calibration);
    if (!c) return std::unexpected(c.error());
    in.cal = *c;
  }
  in.held = std::set<int>(job.holdout.begin(), job.holdout.end());
  for (int h : in.held)
    if (h < 0 || size_t(h) >= in.s.frames.size())
      return fail(ErrorCode::invalid, "holdout: frame " + std::to_string(h) + " is not in the session (frames 0.." +
                                          std::to_string(int(in.s.frames.size()) - 1) + ")");
  in.sensor = resolve_depth_sensor(in.s, in.calibration());
  return in;
}

// The views, decoded in parallel; errors are reported in frame order, and the
// frames left out are counted in the report.
Result<std::vector<View>> load_views(const ReconstructJob& job, const Inputs& in, Report& rep) {
  const Session& s = in.s;
  const std::optional<Intrinsics>& depth_K = in.sensor.intrinsics;
  // Colour is needed for silhouettes and textures only.
  const bool want_color = job.textures || job.geometry != Geometry::depth;
  auto wanted = [&](size_t i) {
    return !in.held.count(int(i)) && in.poses.world_from_camera[i] && !s.frames[i].color.empty();
  };
  std::vector<std::optional<Result<ImageU8>>> colors(s.frames.size());
  std::vector<std::optional<Result<ImageU16>>> depths(s.frames.size());
  std::vector<std::optional<Result<ImageU8>>> mattes(s.frames.size());
  parallel_for(int(s.frames.size()), job.threads, [&](int k) {
    const size_t i = size_t(k);
    if (!wanted(i)) return;
    if (want_color) colors[i] = load_color(s, s.frames[i]);
    if (want_color && !s.frames[i].mask.empty()) mattes[i] = load_mask(s, s.frames[i]);
    if (!s.frames[i].depth.empty()) depths[i] = load_depth(s, s.frames[i]);
  });
  std::vector<View> views;
  Progress progress("load frames", s.frames.size());
  for (size_t i = 0; i < s.frames.size(); ++i, progress.tick()) {
    const Frame& f = s.frames[i];
    if (in.held.count(int(i))) {
      rep.skipped["held_out_views"] += 1;
      continue;
    }
    if (!in.poses.world_from_camera[i]) {
      rep.skipped["frames_without_pose"] += 1;
      continue;
    }
    if (f.color.empty()) {
      rep.skipped["frames_without_color"] += 1;
      continue;
    }
    View v;
    v.frame = int(i);
    auto K = resolve_color_intrinsics(s, f, in.calibration());
    if (!K) return fail("frame " + std::to_string(i) + ": no colour intrinsics (session or calibration)");
    v.K = *K;
    v.world_from_camera = *in.poses.world_from_camera[i];
    auto size_differs = [&](const auto& img, const Intrinsics& K, const std::string& file) {
      return img.width != K.width || img.height != K.height
                 ? fail(fmt::format("frame {}: '{}' is {}x{} but the intrinsics say {}x{}", i, file, img.width, img.height,
                                    K.width, K.height))
                 : Status{};
    };
    if (want_color) {
      Result<ImageU8>& c = *colors[i];
      if (!c) return std::unexpected(c.error());
      if (auto st = size_differs(*c, v.K, f.color); !st) return std::unexpected(st.error());
      v.color = std::move(*c);
      if (mattes[i]) {
        Result<ImageU8>& m = *mattes[i];
        if (!m) return std::unexpected(m.error());
        if (auto st = size_differs(*m, v.K, f.mask); !st) return std::unexpected(st.error());
        v.matte = std::move(*m);
      }
    }
    if (!f.depth.empty()) {
      if (!depth_K) return fail("session has depth frames but no depth intrinsics");
      Result<ImageU16>& d = *depths[i];
      if (!d) return std::unexpected(d.error());
      if (auto st = size_differs(*d, *depth_K, f.depth); !st) return std::unexpected(st.error());
      v.depth = std::move(*d);
      if (in.cal && in.cal->axis) {
        if (const size_t off = mask_off_table(v.depth, in.sensor.unit_m, *depth_K, in.sensor.color_from_depth, *in.cal->axis))
          rep.skipped["depth_samples_off_the_turntable"] += double(off);
      }
      // A view whose depth is all zero (or unreadable as numbers) counts as without depth.
      if (std::none_of(v.depth.data.begin(), v.depth.data.end(), [](uint16_t x) { return x != 0; })) {
        rep.warnings.push_back(fmt::format("frame {}: depth has no valid sample; used for colour only", i));
        v.depth = {};
      }
    }
    views.push_back(std::move(v));
  }
  progress.done();
  if (views.empty()) return fail("no frame to reconstruct from (every frame held out, without pose or without colour)");
  return views;
}

// Silhouettes: the session's mattes where every view has one (any coverage
// counts as inside: the hull keeps what a fractional edge pixel shows), else
// against a uniform backdrop (object-centre sessions); and the geometry mode
// `auto` resolves to; what the mode leaves out is reported.
Result<GeometryPlan> plan_geometry(const ReconstructJob& job, const Session& s, const std::vector<View>& views, Report& rep) {
  const bool has_depth = std::any_of(views.begin(), views.end(), [](const View& v) { return !v.depth.empty(); });
  GeometryPlan plan;
  bool masks_ok = s.layout == Layout::kObjectCentre && job.geometry != Geometry::depth;
  double worst_spread = 0;
  const bool mattes = std::all_of(views.begin(), views.end(), [](const View& v) { return !v.matte.empty(); });
  if (masks_ok && mattes) {
    plan.masks.resize(views.size());
    for (size_t i = 0; i < views.size(); ++i) {
      plan.masks[i] = views[i].matte;
      for (auto& a : plan.masks[i].data) a = a ? 255 : 0;
    }
    rep.params["silhouettes"] = std::string("matte");
  } else if (masks_ok) {
    rep.params["silhouettes"] = std::string("backdrop");
    plan.masks.resize(views.size());
    for (size_t i = 0; i < views.size() && masks_ok; ++i) {
      double spread = 0;
      auto m = backdrop_mask(views[i].color, 0, &spread);
      worst_spread = std::max(worst_spread, spread);
      if (!m) masks_ok = false;
      else plan.masks[i] = std::move(*m);
    }
  }
  plan.mode = job.geometry;
  if (plan.mode == Geometry::automatic) {
    if (has_depth) plan.mode = masks_ok ? Geometry::both : Geometry::depth;
    else if (masks_ok) plan.mode = Geometry::hull;
    else return fail("no depth in the session and no silhouettes (the background is not a uniform backdrop, border spread " +
                     fmt::format("{:.1f}", worst_spread) + " levels): nothing to reconstruct from");
  }
  const std::string_view mode_name = geometry_name(plan.mode);
  if (plan.uses_hull() && !masks_ok)
    return fail(ErrorCode::invalid,
                s.layout != Layout::kObjectCentre
                    ? fmt::format("geometry: {} needs an object-centre session (silhouettes of an object)", mode_name)
                    : fmt::format("geometry: {}: the images' border is not a uniform backdrop (spread {:.1f} levels)",
                                  mode_name, worst_spread));
  if (plan.uses_depth() && !has_depth)
    return fail(ErrorCode::invalid, fmt::format("geometry: {}: the session has no depth", mode_name));
  if (plan.mode == Geometry::depth) rep.skipped["visual_hull_not_needed"] = 1;
  if (plan.mode == Geometry::hull) rep.skipped["depth_fusion_without_depth"] = 1;
  return plan;
}

// Depth points in the world, every 4th pixel, in view order.
std::vector<Eigen::Vector3f> depth_sample(const std::vector<View>& views, const DepthSensorModel& sensor, int threads) {
  std::vector<std::vector<Eigen::Vector3f>> per_view(views.size());
  parallel_for(int(views.size()), threads, [&](int i) {
    const View& v = views[size_t(i)];
    if (v.depth.empty()) return;
    const Eigen::Isometry3d world_from_depth = v.world_from_camera * sensor.color_from_depth;
    const Intrinsics& K = *sensor.intrinsics;
    const double unit = sensor.unit_m;
    const bool pinhole = !K.has_distortion();
    for (int y = 0; y < v.depth.height; y += 4)
      for (int x = 0; x < v.depth.width; x += 4)
        if (const uint16_t d = v.depth.data[size_t(y) * v.depth.width + x]) {
          // Through a pinhole, unproject's own arithmetic inline.
          if (pinhole)
            per_view[size_t(i)].push_back(
                (world_from_depth * (Eigen::Vector3d((x - K.cx) / K.fx, (y - K.cy) / K.fy, 1.0) * (d * unit))).cast<float>());
          else if (auto p = K.unproject({double(x), double(y)}, d * unit))
            per_view[size_t(i)].push_back((world_from_depth * *p).cast<float>());
        }
  });
  std::vector<Eigen::Vector3f> sample;
  for (const auto& pv : per_view) sample.insert(sample.end(), pv.begin(), pv.end());
  return sample;
}

Result<SceneExtent> measure_scene(const ReconstructJob& job, const Inputs& in, const std::vector<View>& views) {
  std::vector<Eigen::Isometry3d> cams;
  for (const auto& v : views) cams.push_back(v.world_from_camera);
  const std::vector<Eigen::Vector3f> sample = depth_sample(views, in.sensor, job.threads);
  SceneExtent e;
  if (in.s.layout == Layout::kObjectCentre) {
    e.centre = optical_axes_centre(cams);
    double nearest = std::numeric_limits<double>::infinity();
    for (const auto& c : cams) nearest = std::min(nearest, (c.translation() - e.centre).norm());
    const double half = 0.6 * nearest;  // the object cannot reach the cameras
    e.box = Eigen::AlignedBox3d(e.centre - Eigen::Vector3d::Constant(half), e.centre + Eigen::Vector3d::Constant(half));
    e.crop = e.box;
    e.view_distance = camera_spacing(cams, e.centre).median_distance_m;
  } else {
    if (sample.empty()) return fail("camera-centre session without depth: nothing to reconstruct");
    Eigen::Vector3d lo, hi;
    for (int a = 0; a < 3; ++a) {
      std::vector<float> c;
      for (const auto& p : sample) c.push_back(p[a]);
      std::sort(c.begin(), c.end());
      lo[a] = c[c.size() / 200], hi[a] = c[c.size() - 1 - c.size() / 200];
    }
    e.box = Eigen::AlignedBox3d(lo, hi);
    e.centre = e.box.center();
    std::vector<double> dist;
    for (size_t i = 0; i < sample.size(); i += 7) {
      double best = std::numeric_limits<double>::infinity();
      for (const auto& c : cams) best = std::min(best, (sample[i].cast<double>() - c.translation()).norm());
      dist.push_back(best);
    }
    std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
    e.view_distance = dist[dist.size() / 2];
  }
  e.spacing = camera_spacing(cams, e.centre);
  const double delta_centre = std::min(e.spacing.max_gap_rad / 2, std::numbers::pi / 2);
  e.focal = views.front().K.fx;
  // The bound holds with alpha the angle at the texel: on the object's side
  // nearest the cameras (distance z_near) two cameras R from the centre are
  // further apart in angle, sin(alpha) = R sin(delta) / z_near, and the screen
  // is closer (bench reconstruct measured e up to 1.28x the centre's figure
  // on the bunny before this).
  e.near_distance = e.view_distance;
  if (in.s.layout == Layout::kObjectCentre && !sample.empty()) {
    std::vector<double> nearest(cams.size());
    parallel_for(int(cams.size()), job.threads, [&](int k) {
      // Squared distances in the loop, one square root at the end: the same minimum.
      const Eigen::Vector3d c = cams[size_t(k)].translation();
      double best = std::numeric_limits<double>::infinity();
      for (size_t i = 0; i < sample.size(); i += 3) best = std::min(best, (sample[i].cast<double>() - c).squaredNorm());
      nearest[size_t(k)] = std::sqrt(best);
    });
    std::nth_element(nearest.begin(), nearest.begin() + nearest.size() / 2, nearest.end());
    e.near_distance = std::min(e.view_distance, nearest[nearest.size() / 2]);
  }
  e.delta = std::asin(std::min(1.0, e.view_distance * std::sin(delta_centre) / e.near_distance));
  e.pixel_m = e.view_distance / e.focal;  // an input pixel at the viewing distance
  return e;
}

// The facet size (given, or from the error bound), with what decided it in
// the report; refused when the volume would not fit.
Result<VoxelChoice> choose_job_voxel(const ReconstructJob& job, const SceneExtent& e, Report& rep) {
  VoxelRequest vr;
  vr.given_m = job.voxel_m;
  vr.target_error_px = job.target_error_px;
  vr.per_region = job.per_region;
  vr.focal_px = e.focal;
  vr.near_distance_m = e.near_distance;
  vr.delta_rad = e.delta;
  vr.pixel_m = e.pixel_m;
  vr.extent_m = e.box.sizes().maxCoeff();
  const VoxelChoice voxel = choose_voxel(vr);
  rep.params["voxel_mode"] = std::string(voxel.automatic ? "auto" : "given");
  if (voxel.automatic) {
    rep.params["voxel_limited_by"] =
        std::string(voxel.limited_by_pixels ? "8 input pixels (cameras closer than the bound needs)" : "error bound");
    rep.params["voxel_bound_m"] = voxel.bound_m;
  }
  rep.warnings.insert(rep.warnings.end(), voxel.warnings.begin(), voxel.warnings.end());
  const double w0 = voxel.base_m;
  rep.params["voxel_m"] = w0;
  rep.params["voxel_coarse_m"] = voxel.coarse_m;
  rep.params["target_error_px"] = job.target_error_px;
  rep.params["camera_gap_deg"] = e.spacing.max_gap_rad * 180 / std::numbers::pi;
  rep.params["view_distance_m"] = e.view_distance;
  rep.params["near_distance_m"] = e.near_distance;
  rep.params["texel_angle_deg"] = e.delta * 180 / std::numbers::pi;
  rep.params["truncation_m"] = job.truncation_voxels * w0;
  rep.errors["predicted_texel_error_px"] = e.focal * texel_error_bound(voxel.coarse_m, e.delta) / e.near_distance;
  const size_t max_cells = size_t(4e8);
  if (std::pow(e.box.sizes().maxCoeff() / w0, 3) > double(max_cells) * 64)
    return fail(fmt::format("voxel_m: {:.3g} m is too small for a {:.3g} m scene (over 2.5e10 cells); choose a larger voxel",
                            w0, e.box.sizes().maxCoeff()));
  return voxel;
}

// Depth fused into the volume; the depth observations are kept for the hull.
std::vector<DepthObservation> fuse_depth(const ReconstructJob& job, const Inputs& in, const std::vector<View>& views,
                                         SparseVolume& volume, Report& rep) {
  std::vector<DepthObservation> depth_obs;
  Progress progress("fuse depth", views.size());
  for (const auto& v : views) {
    if (v.depth.empty()) {
      rep.skipped["views_without_depth"] += 1;
      progress.tick();
      continue;
    }
    depth_obs.push_back({&v.depth, in.sensor.unit_m, *in.sensor.intrinsics, v.world_from_camera * in.sensor.color_from_depth});
  }
  volume.integrate(depth_obs, job.threads, [&] { progress.tick(); });
  progress.done();
  const auto& fs_ = volume.fusion_stats();
  rep.counts["depth_samples"] = double(fs_.depth_samples);
  rep.counts["voxel_updates"] = double(fs_.voxel_updates);
  if (fs_.samples_outside_crop) rep.skipped["depth_samples_outside_object_box"] = double(fs_.samples_outside_crop);
  return depth_obs;
}

void carve_hull(const ReconstructJob& job, const GeometryPlan& plan, const std::vector<View>& views,
                const std::vector<DepthObservation>& depth_obs, const Eigen::AlignedBox3d& box, SparseVolume& volume,
                Report& rep) {
  std::vector<SilhouetteObservation> sil;
  for (size_t i = 0; i < views.size(); ++i) sil.push_back({&plan.masks[i], views[i].K, views[i].world_from_camera});
  const bool both = plan.mode == Geometry::both;
  const HullStats hs = volume.carve_hull(sil, both ? depth_obs : std::vector<DepthObservation>{}, box, job.threads);
  rep.counts["hull_voxels"] = double(hs.hull_voxels);
  rep.counts["hull_cells_tested"] = double(hs.cells_tested);
  rep.skipped["hull_cells_inside_every_silhouette_untested"] = double(hs.cells_interior);
  rep.counts["fuzzy_voxels"] = double(hs.fuzzy_voxels);
  if (both) {
    rep.skipped["hull_voxels_free_by_depth"] = double(hs.carved_by_depth);
    rep.skipped["hull_voxels_inside_by_depth"] = double(hs.solid_by_depth);
  }
}

// Captures without depth: each camera's depth searched behind the hull by
// photo-consistency (reconstruct/photo_depth.h), the hull's surface drawn into
// the camera as where the search starts, and the hull carved where two
// cameras' refined depth shows it empty.
void carve_by_photo_depth(const ReconstructJob& job, const GeometryPlan& plan, const std::vector<View>& views,
                          const SceneExtent& e, double w0, SparseVolume& volume, Report& rep) {
  const Mesh hull = volume.surface_mesh(volume.evidence(w0 / 4));
  const MeshRasterizer raster(hull, MeshRasterizer::Faces::kInwardWound);
  std::vector<PhotoView> pv;
  for (size_t i = 0; i < views.size(); ++i) pv.push_back({&views[i].color, &plan.masks[i], views[i].K, views[i].world_from_camera});
  PhotoDepthParams p;
  p.step_m = w0;
  // 32 voxels behind the hull (at most a quarter of the object's box): on the
  // rig bunny 16 give 90.5 % of the facets within w of the truth, 32 90.8 %,
  // a quarter of the box (64) 90.1 %, in 3.8, 5.6 and 9.7 s; the dino's step
  // took 61 s with a quarter of its box, 8.6 s with 32 voxels.
  p.range_m = std::min(32 * w0, 0.25 * e.box.sizes().maxCoeff());
  std::vector<ImageU16> depth(views.size());
  std::vector<double> unit(views.size(), 1e-4);
  std::vector<PhotoDepthStats> stats(views.size());
  SharedProgress progress("photo depth", views.size());
  parallel_for(int(views.size()), worker_count(job.threads), [&](int i) {
    const View& v = views[size_t(i)];
    const ImageF h = raster.distance_image(v.K, v.world_from_camera);
    const ImageF d = photo_consistent_depth(pv, size_t(i), photo_neighbours(pv, size_t(i), e.centre, p), h, p, &stats[size_t(i)]);
    // Distance along the ray -> depth along the axis, in steps that span the farthest.
    float far = 0;
    for (float x : d.data) far = std::max(far, x);
    unit[size_t(i)] = std::max(1e-6, double(far) / 60000.0);
    ImageU16 z(d.width, d.height, 1, 0);
    for (int y = 0; y < d.height; ++y)
      for (int x = 0; x < d.width; ++x) {
        const float dist = d.at(x, y);
        if (!(dist > 0)) continue;
        if (auto r = v.K.ray({double(x), double(y)}))
          z.at(x, y) = uint16_t(std::clamp(std::lround(dist / r->norm() / unit[size_t(i)]), 1L, 65535L));
      }
    depth[size_t(i)] = std::move(z);
    progress.tick();
  });
  progress.done();
  PhotoDepthStats all;
  for (const auto& s : stats) all += s;
  std::vector<DepthObservation> obs;
  for (size_t i = 0; i < views.size(); ++i) obs.push_back({&depth[i], unit[i], views[i].K, views[i].world_from_camera});
  // A voxel goes when it lies in front of both cameras' depth by its own size
  // (the truncation distance, 4 w, carved a fifth as much of the rig bunny's
  // hull: 1,509 against 7,598 voxels, its facets within w of the truth 79 %
  // against 90 %).
  const size_t carved = volume.carve_free(obs, 2, w0, job.threads);
  rep.counts["photo_depth_pixels_on_hull"] = double(all.pixels_on_hull);
  rep.counts["photo_depth_pixels_at_hull"] = double(all.pixels_at_hull);
  rep.counts["photo_depth_pixels_behind_hull"] = double(all.pixels_behind_hull);
  rep.counts["photo_depth_planes"] = double(all.planes);
  rep.counts["photo_depth_mean_shift_mm"] = all.pixels_behind_hull ? 1000 * all.shift_sum_m / double(all.pixels_behind_hull) : 0;
  rep.skipped["photo_depth_pixels_window_across_the_silhouette"] = double(all.pixels_at_silhouette);
  rep.skipped["photo_depth_pixels_untextured"] = double(all.pixels_untextured);
  rep.skipped["photo_depth_pixels_unmatched"] = double(all.pixels_unmatched);
  rep.skipped["photo_depth_pixels_ambiguous"] = double(all.pixels_ambiguous);
  rep.counts["hull_voxels_carved_by_photo_depth"] = double(carved);
}

Result<OctreePart> build_octree_part(const SparseVolume& volume, double w0, const fs::path& out) {
  Stopwatch clock;
  OctreePart part;
  // A sign change between neighbouring samples is a surface crossing when
  // their difference is at most what fusion can store across one: the
  // clamp behind surfaces (1.5 w) plus a projective distance in front of up
  // to 2 w (grazing rays overestimate). Larger jumps are the truncation
  // band's edge. (With 2 w, the rig bunny's patch mesh had 7,560 boundary
  // edges; with 3.5 w, 1,406.)
  const SurfaceOctree tree = SurfaceOctree::build_from_crossings(volume.crossings(3.5), w0);
  part.records = octree_records(tree);
  part.max_level = tree.max_level();
  part.counts["octree_nodes"] = double(tree.nodes().size());
  part.counts["octree_leaves"] = double(tree.leaves());
  part.counts["octree_levels"] = double(tree.max_level() + 1);
  const Mesh patches = tree.patch_mesh();
  part.counts["patch_triangles"] = double(patches.faces.size());
  part.counts["patch_boundary_edges"] = double(boundary_edges(patches));
  if (!patches.faces.empty()) {
    if (auto st = write_ply_mesh(out / "patches.ply", patches); !st) return std::unexpected(st.error());
    part.patch_mesh = true;
  }
  part.counts["seconds_octree"] = clock.seconds();
  return part;
}

// Every camera's depth: the fused surface rasterized into it (the exact ray
// test per pixel; see camera_depth.h), with the rasterizer's counts.
class CameraDepths {
 public:
  // The fused surface is wound as OpenVDB meshes it (normals inward): faces
  // turned away from a camera are left out.
  CameraDepths(const Mesh& surface, const std::vector<View>& views, const std::vector<EvidenceVoxel>& evidence, double w0,
               bool textures, int threads, Report& rep)
      : raster_(surface, MeshRasterizer::Faces::kInwardWound), stride_(views.size(), 1) {
    // The facets' visibility test reads each camera's depth every `stride`
    // pixels, the spacing on the evidence's far side within w/3 (see
    // visibility_stride). Without textures only that grid is drawn.
    Eigen::AlignedBox3d box_e;
    for (const auto& e : evidence) box_e.extend(e.centre.cast<double>());
    for (size_t i = 0; i < views.size() && !box_e.isEmpty(); ++i) {
      const Eigen::Isometry3d camera_from_world = views[i].world_from_camera.inverse();
      double far = 0;
      for (int c = 0; c < 8; ++c) far = std::max(far, (camera_from_world * box_e.corner(Eigen::AlignedBox3d::CornerType(c))).z());
      stride_[i] = visibility_stride(w0, far, views[i].K);
    }
    rep.counts["visibility_stride_max"] = double(*std::max_element(stride_.begin(), stride_.end()));
    raster_.prepare(textures ? views.front().K : visibility_grid(views.front().K, stride_.front()), threads);
  }
  int stride(size_t view) const { return stride_[view]; }
  ImageF operator()(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera) const {
    MeshRasterizer::Stats rs;
    ImageF d = raster_.distance_image(K, world_from_camera, &rs);
    drawn_ += rs.triangles_drawn, culled_ += rs.triangles_culled, back_ += rs.back_faces, tested_ += rs.pixels_tested;
    back_runs_ += rs.back_faces_in_runs;
    return d;
  }
  size_t triangles_drawn() const { return drawn_; }
  void report(Report& rep) const {
    rep.counts["camera_depth_triangles_drawn"] = double(drawn_);
    rep.counts["camera_depth_pixels_tested"] = double(tested_);
    rep.skipped["camera_depth_triangles_outside_view"] = double(culled_);
    rep.skipped["camera_depth_back_faces"] = double(back_);
    rep.skipped["camera_depth_back_faces_in_whole_runs"] = double(back_runs_);
    const MeshRasterizer::RayTiles tiles = raster_.ray_tiles();
    rep.counts["camera_depth_ray_tiles"] = double(tiles.made);
    rep.skipped["camera_depth_ray_tiles_not_needed"] = double(tiles.total - tiles.made);
  }

 private:
  MeshRasterizer raster_;
  std::vector<int> stride_;
  mutable std::atomic<size_t> drawn_{0}, culled_{0}, back_{0}, back_runs_{0}, tested_{0};
};

std::vector<ModelCamera> model_cameras(const std::vector<View>& views, bool textures) {
  std::vector<ModelCamera> cameras;
  for (const View& v : views) {
    ModelCamera mc;
    mc.intrinsics = v.K;
    mc.world_from_camera = v.world_from_camera;
    mc.session_frame = v.frame;
    if (textures) mc.texture = "cameras/" + frame_file_name(v.frame, "exr");
    cameras.push_back(mc);
  }
  return cameras;
}

// Every camera's depth image, for its texture.
// Where a view's matte says background the camera sees nothing of the
// object: no distance there, so the free-space test discards what is drawn
// in front of it and no facet takes that camera's texels (the hull, carved
// at voxel centres, reaches past the silhouette). `stride`: the image is the
// view's visibility grid (microfacets.h). Returns the pixels cut.
size_t cut_at_matte(ImageF& d, const ImageU8& matte, int stride) {
  if (matte.empty() || d.empty()) return 0;
  const int k = std::max(1, stride), off = (k - 1) / 2;
  size_t cut = 0;
  for (int y = 0; y < d.height; ++y)
    for (int x = 0; x < d.width; ++x) {
      const int mx = off + x * k, my = off + y * k;
      float& v = d.data[size_t(y) * size_t(d.width) + size_t(x)];
      if (v > 0 && mx < matte.width && my < matte.height && matte.at(mx, my) == 0) v = 0, ++cut;
    }
  return cut;
}

std::vector<ImageF> all_camera_depths(const std::vector<View>& views, const CameraDepths& depth, int threads) {
  std::vector<ImageF> distance(views.size());
  SharedProgress progress("camera depth", views.size());
  parallel_for(int(views.size()), worker_count(threads), [&](int i) {
    distance[size_t(i)] = depth(views[size_t(i)].K, views[size_t(i)].world_from_camera);
    progress.tick();
  });
  progress.done();
  return distance;
}

// Colour + alpha (geometry hit) + distance, one OpenEXR per camera, written in parallel.
Status write_textures(const ReconstructJob& job, const std::vector<View>& views, const std::vector<ImageF>& distance,
                      const std::vector<ModelCamera>& cameras) {
  std::vector<Status> written(views.size());
  parallel_for(int(views.size()), worker_count(job.threads), [&](int i) {
    const View& v = views[size_t(i)];
    RgbazImage t{ImageU8(v.K.width, v.K.height, 4), distance[size_t(i)]};
    const size_t ch = size_t(v.color.channels);
    for (size_t p = 0; p < t.rgba.pixels(); ++p) {
      for (size_t k = 0; k < 3; ++k) t.rgba.data[p * 4 + k] = v.color.data[p * ch + std::min(k, ch - 1)];
      t.rgba.data[p * 4 + 3] = t.distance.data[p] > 0 ? 255 : 0;
    }
    written[size_t(i)] = write_rgbaz(job.out / cameras[size_t(i)].texture, t);
  });
  for (const auto& st : written)
    if (!st) return std::unexpected(st.error());
  return {};
}

// The facets and their cameras; without textures each camera's depth is made
// on the visibility grid when the facets' test comes to it.
FacetStats build_model_facets(const ReconstructJob& job, const std::vector<View>& views, const std::vector<EvidenceVoxel>& evidence,
                        const std::vector<ImageF>& distance, const CameraDepths& depth, double w0, Model& model,
                        Report& rep) {
  std::vector<FacetCamera> fc;
  for (size_t i = 0; i < views.size(); ++i) {
    FacetCamera c{views[i].K, views[i].world_from_camera, job.textures ? &distance[i] : nullptr, {}, depth.stride(i)};
    if (!job.textures) {
      const Intrinsics G = visibility_grid(views[i].K, depth.stride(i));
      c.distance_at = [&depth, &views, i, G] {
        ImageF d = depth(G, views[i].world_from_camera);
        cut_at_matte(d, views[i].matte, depth.stride(i));
        return d;
      };
      rep.skipped["camera_depth_pixels_off_the_visibility_grid"] +=
          double(views[i].K.width) * views[i].K.height - double(G.width) * G.height;
    }
    fc.push_back(std::move(c));
  }
  FacetOptions fo;
  fo.voxel_m = w0;
  fo.per_region = job.per_region;
  fo.threads = job.threads;
  const FacetStats st = build_facets(evidence, fc, fo, model.facets, model.facet_cameras);
  rep.counts["facets"] = double(st.facets);
  rep.counts["facets_fine"] = double(st.fine);
  rep.counts["facets_coarse"] = double(st.coarse);
  rep.counts["facets_fuzzy"] = double(st.fuzzy);
  rep.counts["facet_camera_links"] = double(st.camera_links);
  rep.counts["cameras"] = double(views.size());
  rep.skipped["facets_seen_by_no_camera"] = double(st.unseen);
  rep.skipped["facet_camera_pairs_occluded"] = double(st.occluded);
  rep.skipped["facet_camera_pairs_outside_image"] = double(st.outside_image);
  depth.report(rep);
  return st;
}

Eigen::AlignedBox3d facet_bounds(const std::vector<FacetRecord>& facets, const Eigen::Vector3d& centre) {
  Eigen::AlignedBox3d bounds;
  for (const auto& f : facets) {
    const Eigen::Vector3d c(f.center[0], f.center[1], f.center[2]);
    bounds.extend(c - Eigen::Vector3d::Constant(f.size));
    bounds.extend(c + Eigen::Vector3d::Constant(f.size));
  }
  if (bounds.isEmpty()) bounds = Eigen::AlignedBox3d(centre, centre);
  return bounds;
}

// The synthetic rig knows the truth: the model's error against it.
Result<ReconstructTruth> check_against_truth(const ReconstructJob& job, const Session& s, const Model& model, double w0,
                                             Report& rep) {
  const fs::path truth_mesh = s.root / "ground_truth" / "geometry.ply";
  auto mesh = read_ply_mesh(truth_mesh);
  if (!mesh) return std::unexpected(mesh.error());
  std::vector<FacetRecord> solid;
  for (const auto& f : model.facets)
    if (f.size <= w0 * 1.01) solid.push_back(f);
  const SurfaceDistance distance_to_truth(*mesh, w0 / 5);
  ReconstructTruth truth;
  truth.all = distance_to_truth.error(model.facets);
  truth.fine = distance_to_truth.error(solid);
  rep.errors["facets_within_w_fraction"] = truth.all.within_size;
  rep.errors["facet_distance_median_m"] = truth.all.median_m;
  rep.errors["facet_distance_p99_m"] = truth.all.p99_m;
  rep.errors["fine_facets_within_w_fraction"] = truth.fine.within_size;
  if (job.textures) {
    auto de = camera_depth_error(model, job.out, s.root);
    if (!de) return std::unexpected(de.error());
    truth.camera_depth = *de;
    rep.errors["camera_depth_median_m"] = de->median_m;
    rep.errors["camera_depth_p90_m"] = de->p90_m;
    rep.errors["camera_depth_missing_fraction"] = de->missing;
  }
  if (fs::exists(s.root / "ground_truth" / "strands.ply")) {
    auto sc = strand_coverage(model, s.root);
    if (!sc) return std::unexpected(sc.error());
    truth.strands = *sc;
    rep.errors["strand_pixels_covered_fraction"] = sc->covered;
    rep.errors["facet_pixels_on_background_fraction"] = sc->background;
  }
  return truth;
}

}  // namespace

// The fit's background: the session's, else the median of the photos'
// border colours in object-centre sessions (as eval's), else black.
std::array<float, 3> fit_background(const Session& s, const std::vector<View>& views) {
  if (s.background) return *s.background;
  std::array<float, 3> bg{0, 0, 0};
  if (s.layout != Layout::kObjectCentre) return bg;
  std::array<std::vector<double>, 3> c;
  for (const View& v : views) {
    const Backdrop b = border_backdrop(v.color);
    for (size_t k = 0; k < 3 && !b.color.empty(); ++k) c[k].push_back(b.color[std::min(k, b.color.size() - 1)] / 255.0);
  }
  for (size_t k = 0; k < 3; ++k) bg[k] = c[k].empty() ? 0.f : float(median(c[k]));
  return bg;
}

// Fitted billboards: the candidates from the volume, fitted to the training
// photos (only the views the model is built from), written as splats.bin
// with the fit's error against seconds as fit.csv.
Status fit_step(const ReconstructJob& job, const Session& s, const std::vector<View>& views, const SparseVolume& volume,
                double w0, const ImageU8* plate, const Mesh& depth_surface, Model& model, ReconstructSummary& sum) {
  Report& rep = sum.report;
  const auto anchors = volume.fit_candidates(2 * w0);
  if (anchors.empty()) {
    rep.warnings.push_back("fit: no voxel to start from (no hull and no fused surface): no fitted billboards");
    return {};
  }
  std::vector<ImageU8> rgb(views.size());
  std::vector<SplatView> sv;
  for (size_t i = 0; i < views.size(); ++i) {
    const ImageU8& c = views[i].color;
    if (c.channels == 3) {
      sv.push_back({views[i].K, views[i].world_from_camera, &c, plate, views[i].matte.empty() ? nullptr : &views[i].matte});
      continue;
    }
    rgb[i] = ImageU8(c.width, c.height, 3);
    for (size_t p = 0; p < c.pixels(); ++p)
      for (size_t k = 0; k < 3; ++k) rgb[i].data[p * 3 + k] = c.data[p * size_t(c.channels) + std::min<size_t>(k, size_t(c.channels) - 1)];
    sv.push_back({views[i].K, views[i].world_from_camera, &rgb[i], plate, views[i].matte.empty() ? nullptr : &views[i].matte});
  }
  // Where the capture has depth, each camera's distance to the fused depth
  // surface (not the hull's closure around what depth did not see).
  std::vector<ImageF> depth(views.size());
  if (job.fit_depth_weight > 0 && !depth_surface.faces.empty()) {
    const MeshRasterizer raster(depth_surface, MeshRasterizer::Faces::kInwardWound);
    parallel_for(int(views.size()), job.threads, [&](int i) {
      depth[size_t(i)] = raster.distance_image(views[size_t(i)].K, views[size_t(i)].world_from_camera);
      sv[size_t(i)].depth = &depth[size_t(i)];
    });
    rep.counts["fit_depth_views"] = double(views.size());
  } else if (job.fit_depth_weight > 0) {
    rep.skipped["fit_depth_without_a_depth_surface"] = 1;
  }
  SplatFitOptions o;
  o.seconds = job.fit_seconds;
  o.sh_degree = job.fit_sh_degree;
  o.max_epochs = job.fit_epochs;
  o.max_facets = job.fit_max_facets;
  o.stage_time_growth = job.fit_stage_growth;
  o.threads = job.threads;
  o.background = fit_background(s, views);
  o.random_background = job.fit_random_background;
  o.ssim_weight = job.fit_ssim_weight;
  o.loss = job.fit_loss == "l1" ? SplatFitOptions::Loss::l1 : SplatFitOptions::Loss::l2;
  o.pixel_filter_px2 = job.fit_pixel_filter_px2;
  o.split_by = job.fit_split == "gradient" ? SplatFitOptions::SplitBy::gradient : SplatFitOptions::SplitBy::usage;
  o.depth_weight = job.fit_depth_weight;
  o.seconds_marks = job.fit_snapshots;
  Progress bar("fit", 1000);
  size_t shown = 0;
  o.on_progress = [&](double f) {
    const size_t at = size_t(f * 1000);
    if (at > shown) bar.tick(at - shown), shown = at;
  };
  auto splats = init_splats(anchors, float(w0), sv, o);
  auto fit = fit_splats(splats, sv, o);
  bar.done();
  if (!fit) return std::unexpected(fit.error());
  const SplatLayout layout{job.fit_sh_degree, float(o.pixel_filter_px2)};
  auto records = [&](const std::vector<Splat>& in) {
    std::vector<float> out;
    out.reserve(in.size() * size_t(layout.stride()));
    for (const Splat& p : in) {
      const Eigen::Vector3f c = p.centre();
      out.insert(out.end(), {c.x(), c.y(), c.z(), p.sigma(), p.opacity()});
      for (int k = 0; k < 3 * layout.coeffs(); ++k) out.push_back(p.sh[size_t(k)]);
    }
    return out;
  };
  model.splat_layout = layout;
  model.splats = records(splats);
  order_splats_spatially(model.splats, layout.stride());  // a screen tile's facets near each other in memory
  model.background = o.background;
  SweepTable curve;
  curve.columns = {"seconds", "epoch", "scale", "train_psnr_db", "facets"};
  for (const auto& p : fit->curve) curve.rows.push_back({p.seconds, double(p.epoch), double(p.scale), p.train_psnr_db, double(p.splats)});
  if (auto st = curve.write_csv(job.out / "fit.csv"); !st) return st;
  for (const auto& [at, snap] : fit->snapshots) {
    const std::string name = fmt::format("splats_{:.0f}s.bin", at);
    if (auto st = save_splat_payload(job.out / name, records(snap)); !st) return st;
  }
  fit->snapshots.clear();
  rep.counts["fit_candidates"] = double(fit->initial);
  rep.counts["fit_refined_from"] = double(fit->refined_from);
  rep.counts["fit_split"] = double(fit->split);
  rep.counts["fit_facets"] = double(fit->final_count);
  rep.counts["fit_epochs"] = double(fit->epochs);
  rep.counts["fit_steps"] = double(fit->steps);
  rep.counts["fit_seconds"] = fit->seconds;
  rep.counts["fit_seconds_initial_error"] = fit->seconds_initial;
  rep.counts["fit_seconds_project"] = fit->seconds_project;
  rep.counts["fit_seconds_raster"] = fit->seconds_raster;
  rep.counts["fit_seconds_update"] = fit->seconds_update;
  rep.counts["fit_bytes"] = double(model.splats.size() * 4);
  rep.skipped["fit_facets_pruned"] = double(fit->pruned);
  rep.errors["fit_initial_psnr_db"] = fit->initial_psnr_db;
  rep.errors["fit_train_psnr_db"] = fit->train_psnr_db;
  rep.params["fit_background"] = plate ? std::string("backdrop_plate")
                                       : fmt::format("{:.3g},{:.3g},{:.3g}", o.background[0], o.background[1], o.background[2]);
  rep.params["fit_sh_degree"] = double(job.fit_sh_degree);
  rep.params["fit_ssim_weight"] = job.fit_ssim_weight;
  rep.params["fit_loss"] = job.fit_loss;
  rep.params["fit_pixel_filter_px2"] = job.fit_pixel_filter_px2;
  rep.params["fit_split"] = job.fit_split;
  rep.params["fit_max_facets"] = double(job.fit_max_facets);
  rep.params["fit_stage_growth"] = job.fit_stage_growth;
  rep.params["fit_depth_weight"] = job.fit_depth_weight;
  if (fit->initial_depth_rms_m > 0) {
    rep.errors["fit_initial_depth_rms_mm"] = fit->initial_depth_rms_m * 1e3;
    rep.errors["fit_depth_rms_mm"] = fit->depth_rms_m * 1e3;
  }
  sum.fit = std::move(*fit);
  return {};
}

Status ReconstructJob::validate() const {
  if (!(target_error_px > 0)) return fail(ErrorCode::invalid, "target_error_px: must be > 0 pixels");
  if (!(truncation_voxels >= 1)) return fail(ErrorCode::invalid, "truncation_voxels: must be at least 1 voxel");
  if (voxel_m && !(*voxel_m > 0 && std::isfinite(*voxel_m)))
    return fail(ErrorCode::invalid, "voxel_m: must be 'auto' or a positive number of metres");
  if (threads < 0) return fail(ErrorCode::invalid, "threads: must be >= 0 (0 = all cores)");
  if (!(fit_seconds >= 0) || !std::isfinite(fit_seconds)) return fail(ErrorCode::invalid, "fit_seconds: must be >= 0 seconds");
  if (fit_sh_degree < 0 || fit_sh_degree > 2) return fail(ErrorCode::invalid, "fit_sh_degree: must be 0, 1 or 2");
  if (!(fit_ssim_weight >= 0 && fit_ssim_weight < 1)) return fail(ErrorCode::invalid, "fit_ssim_weight: must be in [0, 1)");
  if (fit_loss != "l2" && fit_loss != "l1") return fail(ErrorCode::invalid, "fit_loss: must be l2 or l1");
  if (fit_split != "usage" && fit_split != "gradient")
    return fail(ErrorCode::invalid, "fit_split: must be usage or gradient");
  if (!(fit_pixel_filter_px2 >= 0 && fit_pixel_filter_px2 <= 4))
    return fail(ErrorCode::invalid, "fit_pixel_filter_px2: must be in [0, 4] (pixels^2)");
  if (!(fit_depth_weight >= 0) || !std::isfinite(fit_depth_weight)) return fail(ErrorCode::invalid, "fit_depth_weight: must be >= 0 and finite");
  if (fit_epochs < 0) return fail(ErrorCode::invalid, "fit_epochs: must be >= 0 (0: the seconds alone)");
  if (fit_max_facets < 1000 || fit_max_facets > 20000000)
    return fail(ErrorCode::invalid, "fit_max_facets: must be between 1,000 and 20,000,000");
  if (!(fit_stage_growth >= 0.25 && fit_stage_growth <= 16))
    return fail(ErrorCode::invalid, "fit_stage_growth: must be between 0.25 and 16");
  return {};
}

// The job's steps, each timed into the report (seconds_STEP, cpu_STEP): load,
// geometry and voxel size, fusion, hull, evidence and the fused surface (the
// octree in a task of its own alongside), camera depth, textures, facets,
// write; then the check against the synthetic rig's truth where there is one.
Result<ReconstructSummary> run_reconstruct_job(const ReconstructJob& job) {
  Stopwatch total;
  ReconstructSummary sum;
  Report& rep = sum.report;
  rep.stage = "reconstruct";
  Timer timer{rep, {}};
  if (auto st = job.validate(); !st) return std::unexpected(st.error());
  auto in = load_inputs(job);
  if (!in) return std::unexpected(in.error());
  auto views = load_views(job, *in, rep);
  if (!views) return std::unexpected(views.error());
  timer.lap("load");
  auto plan = plan_geometry(job, in->s, *views, rep);
  if (!plan) return std::unexpected(plan.error());
  auto extent = measure_scene(job, *in, *views);
  if (!extent) return std::unexpected(extent.error());
  auto voxel = choose_job_voxel(job, *extent, rep);
  if (!voxel) return std::unexpected(voxel.error());
  const double w0 = voxel->base_m;
  sum.geometry = plan->mode;
  sum.voxel = *voxel;
  sum.view_distance_m = extent->view_distance;
  sum.near_distance_m = extent->near_distance;
  sum.cameras = views->size();
  sum.held_out_views = in->held.size();
  sum.views_without_depth = size_t(std::count_if(views->begin(), views->end(), [](const View& v) { return v.depth.empty(); }));
  rep.params["geometry"] = std::string(geometry_name(plan->mode));
  rep.params["poses"] = in->poses.source;

  SparseVolume volume(w0, job.truncation_voxels * w0, extent->crop);
  std::vector<DepthObservation> depth_obs;
  if (plan->uses_depth()) depth_obs = fuse_depth(job, *in, *views, volume, rep);
  sum.seconds_fusion = timer.lap("fusion");
  if (plan->uses_hull()) carve_hull(job, *plan, *views, depth_obs, extent->box, volume, rep);
  timer.lap("hull");
  if (job.photo_depth && plan->mode == Geometry::hull) {
    carve_by_photo_depth(job, *plan, *views, *extent, w0, volume, rep);
    timer.lap("photo_depth");
  } else if (job.photo_depth) {
    rep.skipped["photo_depth_with_depth_from_the_sensor"] = 1;
  }
  // The depth images and silhouettes are not read again: let them go (on a
  // 200-photo capture at 12 MP they are 7 GB of the job's memory).
  depth_obs = {};
  plan->masks = {};
  for (View& v : *views) v.depth = {};

  std::error_code ec;
  fs::create_directories(job.out / "cameras", ec);
  if (ec) return fail("cannot create '" + (job.out / "cameras").string() + "': " + ec.message());
  // The octree is built from the volume alone alongside the evidence, the
  // cameras' depth and the facets: its seconds overlap theirs.
  std::future<Result<OctreePart>> octree_part =
      std::async(std::launch::async, [&] { return build_octree_part(volume, w0, job.out); });

  const auto evidence = volume.evidence(w0 / 4);
  if (evidence.empty()) rep.warnings.push_back("no voxel holds surface evidence: the model has no facets");
  rep.counts["evidence_voxels"] = double(evidence.size());
  rep.counts["active_voxels"] = double(volume.active_voxels());
  rep.skipped["voxels_without_evidence"] = double(volume.active_voxels()) - double(evidence.size());
  rep.counts["volume_bytes"] = double(volume.memory_bytes());
  size_t depth_faces = 0;
  const Mesh surface = volume.surface_mesh(evidence, &depth_faces);
  rep.counts["surface_triangles"] = double(surface.faces.size());
  // Written in a task of its own while the cameras' depth is made.
  std::future<Status> surface_written = std::async(std::launch::async, [&]() -> Status {
    if (surface.faces.empty()) return {};
    return write_ply_mesh(job.out / "surface.ply", surface);
  });
  timer.lap("evidence");

  const CameraDepths depth(surface, *views, evidence, w0, job.textures, job.threads, rep);
  Model model;
  model.voxel_size_m = w0;
  model.session = in->s.name;
  model.background = in->s.background;
  model.cameras = model_cameras(*views, job.textures);
  // Every camera's depth goes into its texture; without textures each one is
  // made when the facets' visibility test comes to it.
  std::vector<ImageF> distance(views->size());
  if (job.textures) {
    distance = all_camera_depths(*views, depth, job.threads);
    size_t cut = 0;
    for (size_t i = 0; i < views->size(); ++i) cut += cut_at_matte(distance[i], (*views)[i].matte, 1);
    if (cut) rep.skipped["camera_depth_pixels_outside_the_matte"] = double(cut);
    sum.camera_depth_pixels_outside_matte = cut;
  }
  timer.lap("camera_depth");
  if (job.textures) {
    if (auto st = write_textures(job, *views, distance, model.cameras); !st) return std::unexpected(st.error());
  } else {
    rep.skipped["camera_textures_not_written"] = double(views->size());
  }
  timer.lap("textures");
  sum.facets = build_model_facets(job, *views, evidence, distance, depth, w0, model, rep);
  sum.camera_depth_triangles_drawn = depth.triangles_drawn();
  timer.lap("facets");

  // The backdrop plate, where the capture is of an object whose backdrop
  // stays put in the images and is not one colour (needed only by what
  // draws from the photos or fits to them).
  std::optional<ImageU8> plate;
  if (in->s.layout == Layout::kObjectCentre && (job.textures || job.fit_seconds > 0)) {
    // Where each camera sees none of the surface; without textures each
    // camera's distances are made and let go one at a time (all of them at
    // once are 4 bytes a pixel of every photo).
    std::vector<const ImageU8*> photos;
    std::vector<ImageU8> empty(views->size());
    SharedProgress progress("backdrop: camera depth", views->size());
    parallel_for(int(views->size()), worker_count(job.threads), [&](int i) {
      const View& v = (*views)[size_t(i)];
      const ImageF made = job.textures ? ImageF{} : depth(v.K, v.world_from_camera);
      const ImageF& d = job.textures ? distance[size_t(i)] : made;
      ImageU8 e(d.width, d.height, 1);
      for (size_t p = 0; p < d.pixels(); ++p) e.data[p] = d.data[p] > 0 ? 0 : 255;
      empty[size_t(i)] = std::move(e);
      progress.tick();
    });
    progress.done();
    for (const View& v : *views) photos.push_back(&v.color);
    BackdropPlateResult pr = make_backdrop_plate(photos, empty, fit_background(in->s, *views));
    rep.counts["backdrop_plate_kept_share"] = pr.kept_share;
    if (pr.plate) rep.counts["backdrop_plate_filled_share"] = pr.filled_share;
    rep.errors["backdrop_plate_spread"] = pr.spread;
    if (pr.plate) {
      if (auto st = write_image(job.out / "backdrop.png", *pr.plate); !st) return std::unexpected(st.error());
      model.backdrop = "backdrop.png";
      plate = std::move(pr.plate);
    } else {
      rep.skipped["backdrop_plate_" + pr.skipped] = 1;
    }
    timer.lap("backdrop");
  } else {
    rep.skipped["backdrop_plate_not_an_object_capture_or_nothing_draws_from_photos"] = 1;
  }

  if (job.fit_seconds > 0) {
    Mesh depth_surface;
    if (job.fit_depth_weight > 0) {
      depth_surface.vertices = surface.vertices;
      depth_surface.faces.assign(surface.faces.begin(), surface.faces.begin() + std::ptrdiff_t(depth_faces));
    }
    if (auto st = fit_step(job, in->s, *views, volume, w0, plate ? &*plate : nullptr, depth_surface, model, sum); !st)
      return std::unexpected(st.error());
    timer.lap("fit");
  }

  model.bounds = facet_bounds(model.facets, extent->centre);
  Result<OctreePart> part = octree_part.get();
  if (!part) return std::unexpected(part.error());
  model.octree = std::move(part->records);
  model.octree_max_level = part->max_level;
  for (const auto& [k, v] : part->counts) rep.counts[k] = v;
  if (part->patch_mesh) model.patch_mesh = "patches.ply";
  timer.lap("octree_wait");
  if (auto st = surface_written.get(); !st) return std::unexpected(st.error());
  if (!surface.faces.empty()) model.surface_mesh = "surface.ply";
  if (auto st = save_model(job.out, model); !st) return std::unexpected(st.error());
  timer.lap("write");
  rep.counts["model_bytes"] = double(model.facets.size() * sizeof(FacetRecord) + model.facet_cameras.size() * 4);
  rep.seconds = sum.seconds = total.seconds();

  // Not counted in the build seconds.
  if (fs::exists(in->s.root / "ground_truth" / "geometry.ply")) {
    auto truth = check_against_truth(job, in->s, model, w0, rep);
    if (!truth) return std::unexpected(truth.error());
    sum.truth = std::move(*truth);
    timer.lap("truth_check");
  }
  return sum;
}

}  // namespace s2r
