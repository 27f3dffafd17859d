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
#include "reconstruct/camera_depth.h"
#include "reconstruct/frame_inputs.h"
#include "reconstruct/fusion.h"
#include "reconstruct/microfacets.h"
#include "reconstruct/model.h"
#include "reconstruct/octree.h"
#include "reconstruct/poses.h"
#include "reconstruct/rig_eval.h"

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
  void lap(const std::string& step) {
    rep.counts["seconds_" + step] = clock.seconds();
    const double c = cpu_now();
    rep.counts["cpu_" + step] = c - cpu0;
    cpu0 = c;
    clock = Stopwatch();
  }
};

}  // namespace

Status ReconstructJob::validate() const {
  if (!(target_error_px > 0)) return fail(ErrorCode::invalid, "target_error_px: must be > 0 pixels");
  if (!(truncation_voxels >= 1)) return fail(ErrorCode::invalid, "truncation_voxels: must be at least 1 voxel");
  if (voxel_m && !(*voxel_m > 0 && std::isfinite(*voxel_m)))
    return fail(ErrorCode::invalid, "voxel_m: must be 'auto' or a positive number of metres");
  if (threads < 0) return fail(ErrorCode::invalid, "threads: must be >= 0 (0 = all cores)");
  return {};
}

Result<Report> run_reconstruct_job(const ReconstructJob& job) {
  Stopwatch total;
  Report rep;
  rep.stage = "reconstruct";
  Timer timer{rep, {}};
  if (auto st = job.validate(); !st) return std::unexpected(st.error());

  // Image headers are not probed here: the frames the job uses are decoded
  // below and their sizes checked against the intrinsics then.
  auto session = load_session(job.session, {.check_images = false});
  if (!session) return std::unexpected(session.error());
  const Session& s = *session;
  auto poses = resolve_frame_poses(s, job.poses, job.calibration);
  if (!poses) return std::unexpected(poses.error());
  std::optional<Calibration> cal;
  if (!job.calibration.empty()) {
    auto c = load_calibration(job.calibration);
    if (!c) return std::unexpected(c.error());
    cal = *c;
  }
  std::set<int> held(job.holdout.begin(), job.holdout.end());
  for (int h : held)
    if (h < 0 || size_t(h) >= s.frames.size())
      return fail(ErrorCode::invalid, "holdout: frame " + std::to_string(h) + " is not in the session (frames 0.." +
                                          std::to_string(int(s.frames.size()) - 1) + ")");

  // Depth sensor model.
  const DepthSensorModel sensor = resolve_depth_sensor(s, cal ? &*cal : nullptr);
  const std::optional<Intrinsics>& depth_K = sensor.intrinsics;
  const Eigen::Isometry3d& color_from_depth = sensor.color_from_depth;
  const double unit = sensor.unit_m;

  // Views: frames with a pose and a colour image, not held out.
  struct View {
    int frame;
    Intrinsics K;
    Eigen::Isometry3d world_from_camera;
    ImageU8 color;
    ImageU16 depth;
  };
  std::vector<View> views;
  {
    // Colour is needed for silhouettes and textures only.
    const bool want_color = job.textures || job.geometry != Geometry::depth;
    auto wanted = [&](size_t i) {
      return !held.count(int(i)) && poses->world_from_camera[i] && !s.frames[i].color.empty();
    };
    // The images are decoded in parallel; errors are reported below in frame order.
    std::vector<std::optional<Result<ImageU8>>> colors(s.frames.size());
    std::vector<std::optional<Result<ImageU16>>> depths(s.frames.size());
    parallel_for(int(s.frames.size()), job.threads, [&](int k) {
      const size_t i = size_t(k);
      if (!wanted(i)) return;
      if (want_color) colors[i] = load_color(s, s.frames[i]);
      if (!s.frames[i].depth.empty()) depths[i] = load_depth(s, s.frames[i]);
    });
    Progress progress("load frames", s.frames.size());
    for (size_t i = 0; i < s.frames.size(); ++i, progress.tick()) {
      const Frame& f = s.frames[i];
      if (held.count(int(i))) {
        rep.skipped["held_out_views"] += 1;
        continue;
      }
      if (!poses->world_from_camera[i]) {
        rep.skipped["frames_without_pose"] += 1;
        continue;
      }
      if (f.color.empty()) {
        rep.skipped["frames_without_color"] += 1;
        continue;
      }
      View v;
      v.frame = int(i);
      auto K = resolve_color_intrinsics(s, f, cal ? &*cal : nullptr);
      if (!K) return fail("frame " + std::to_string(i) + ": no colour intrinsics (session or --calibration)");
      v.K = *K;
      v.world_from_camera = *poses->world_from_camera[i];
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
      }
      if (!f.depth.empty()) {
        if (!depth_K) return fail("session has depth frames but no depth intrinsics");
        Result<ImageU16>& d = *depths[i];
        if (!d) return std::unexpected(d.error());
        if (auto st = size_differs(*d, *depth_K, f.depth); !st) return std::unexpected(st.error());
        v.depth = std::move(*d);
        if (cal && cal->axis) {
          if (const size_t off = mask_off_table(v.depth, unit, *depth_K, color_from_depth, *cal->axis))
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
  }
  if (views.empty()) return fail("no frame to reconstruct from (every frame held out, without pose or without colour)");
  timer.lap("load");
  const bool has_depth = std::any_of(views.begin(), views.end(), [](const View& v) { return !v.depth.empty(); });

  // Silhouettes (object-centre sessions against a uniform backdrop).
  std::vector<ImageU8> masks;
  bool masks_ok = s.layout == Layout::kObjectCentre && job.geometry != Geometry::depth;
  double worst_spread = 0;
  if (masks_ok) {
    masks.resize(views.size());
    for (size_t i = 0; i < views.size() && masks_ok; ++i) {
      double spread = 0;
      auto m = backdrop_mask(views[i].color, 0, &spread);
      worst_spread = std::max(worst_spread, spread);
      if (!m) masks_ok = false;
      else masks[i] = std::move(*m);
    }
  }
  Geometry mode = job.geometry;
  if (mode == Geometry::automatic) {
    if (has_depth) mode = masks_ok ? Geometry::both : Geometry::depth;
    else if (masks_ok) mode = Geometry::hull;
    else return fail("no depth in the session and no silhouettes (the background is not a uniform backdrop, border spread " +
                     fmt::format("{:.1f}", worst_spread) + " levels): nothing to reconstruct from");
  }
  const std::string_view mode_name = geometry_name(mode);
  if ((mode == Geometry::hull || mode == Geometry::both) && !masks_ok)
    return fail(ErrorCode::invalid,
                s.layout != Layout::kObjectCentre
                    ? fmt::format("geometry: {} needs an object-centre session (silhouettes of an object)", mode_name)
                    : fmt::format("geometry: {}: the images' border is not a uniform backdrop (spread {:.1f} levels)",
                                  mode_name, worst_spread));
  if ((mode == Geometry::depth || mode == Geometry::both) && !has_depth)
    return fail(ErrorCode::invalid, fmt::format("geometry: {}: the session has no depth", mode_name));
  if (mode == Geometry::depth) rep.skipped["visual_hull_not_needed"] = 1;
  if (mode == Geometry::hull) rep.skipped["depth_fusion_without_depth"] = 1;

  // Where the object is, and how far apart the cameras are.
  std::vector<Eigen::Isometry3d> cams;
  for (const auto& v : views) cams.push_back(v.world_from_camera);
  std::vector<Eigen::Vector3f> sample;  // depth points in the world, every 4th pixel, in view order
  {
    std::vector<std::vector<Eigen::Vector3f>> per_view(views.size());
    parallel_for(int(views.size()), job.threads, [&](int i) {
      const View& v = views[size_t(i)];
      if (v.depth.empty()) return;
      const Eigen::Isometry3d world_from_depth = v.world_from_camera * color_from_depth;
      const Intrinsics& K = *depth_K;
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
    for (const auto& pv : per_view) sample.insert(sample.end(), pv.begin(), pv.end());
  }
  Eigen::Vector3d centre;
  double view_distance;
  std::optional<Eigen::AlignedBox3d> crop;
  Eigen::AlignedBox3d box;
  if (s.layout == Layout::kObjectCentre) {
    centre = optical_axes_centre(cams);
    double nearest = std::numeric_limits<double>::infinity();
    for (const auto& c : cams) nearest = std::min(nearest, (c.translation() - centre).norm());
    const double half = 0.6 * nearest;  // the object cannot reach the cameras
    box = Eigen::AlignedBox3d(centre - Eigen::Vector3d::Constant(half), centre + Eigen::Vector3d::Constant(half));
    crop = box;
    view_distance = camera_spacing(cams, centre).median_distance_m;
  } else {
    if (sample.empty()) return fail("camera-centre session without depth: nothing to reconstruct");
    Eigen::Vector3d lo, hi;
    for (int a = 0; a < 3; ++a) {
      std::vector<float> c;
      for (const auto& p : sample) c.push_back(p[a]);
      std::sort(c.begin(), c.end());
      lo[a] = c[c.size() / 200], hi[a] = c[c.size() - 1 - c.size() / 200];
    }
    box = Eigen::AlignedBox3d(lo, hi);
    centre = box.center();
    std::vector<double> dist;
    for (size_t i = 0; i < sample.size(); i += 7) {
      double best = std::numeric_limits<double>::infinity();
      for (const auto& c : cams) best = std::min(best, (sample[i].cast<double>() - c.translation()).norm());
      dist.push_back(best);
    }
    std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
    view_distance = dist[dist.size() / 2];
  }
  const CameraSpacing spacing = camera_spacing(cams, centre);
  const double delta_centre = std::min(spacing.max_gap_rad / 2, std::numbers::pi / 2);
  const double focal = views.front().K.fx;
  // The bound holds with alpha the angle at the texel: on the object's side
  // nearest the cameras (distance z_near) two cameras R from the centre are
  // further apart in angle, sin(alpha) = R sin(delta) / z_near, and the screen
  // is closer (bench reconstruct measured e up to 1.28x the centre's figure
  // on the bunny before this).
  double near_distance = view_distance;
  if (s.layout == Layout::kObjectCentre && !sample.empty()) {
    std::vector<double> nearest(cams.size());
    parallel_for(int(cams.size()), job.threads, [&](int k) {
      // Squared distances in the loop, one square root at the end: the same minimum.
      const Eigen::Vector3d c = cams[size_t(k)].translation();
      double best = std::numeric_limits<double>::infinity();
      for (size_t i = 0; i < sample.size(); i += 3) best = std::min(best, (sample[i].cast<double>() - c).squaredNorm());
      nearest[size_t(k)] = std::sqrt(best);
    });
    std::nth_element(nearest.begin(), nearest.begin() + nearest.size() / 2, nearest.end());
    near_distance = std::min(view_distance, nearest[nearest.size() / 2]);
  }
  const double delta = std::asin(std::min(1.0, view_distance * std::sin(delta_centre) / near_distance));
  const double pixel_m = view_distance / focal;  // an input pixel at the viewing distance
  double w0;
  if (job.voxel_m) {
    w0 = *job.voxel_m;
    rep.params["voxel_mode"] = std::string("given");
  } else {
    // Densely spaced cameras allow large facets by the bound alone; a facet is
    // still kept within kMaxFacetPixels input pixels, beyond which it blurs
    // detail the photos hold and its clipping window (w/2) stops telling
    // surfaces apart.
    constexpr double kMaxFacetPixels = 8;
    double w_max = voxel_for_error(job.target_error_px, focal, near_distance, delta);
    if (w_max > kMaxFacetPixels * pixel_m) {
      w_max = kMaxFacetPixels * pixel_m;
      rep.params["voxel_limited_by"] = std::string("8 input pixels (cameras closer than the bound needs)");
    } else {
      rep.params["voxel_limited_by"] = std::string("error bound");
    }
    w0 = job.per_region ? w_max / 2 : w_max;
    rep.params["voxel_mode"] = std::string("auto");
    rep.params["voxel_bound_m"] = w_max;
    if (w0 < 2 * pixel_m) {
      rep.warnings.push_back(fmt::format("the error bound allows {:.2f} mm facets, under two input pixels ({:.2f} mm): "
                                         "using two pixels (cameras this close in angle need no finer facets)",
                                         1e3 * w0, 2e3 * pixel_m));
      w0 = 2 * pixel_m;
    }
    const double extent = box.sizes().maxCoeff();
    if (w0 > extent / 4) w0 = extent / 4;
  }
  if (w0 < pixel_m)
    rep.warnings.push_back(fmt::format("voxel {:.3f} mm is below one input pixel at the viewing distance ({:.3f} mm): "
                                       "facets finer than the photos",
                                       1e3 * w0, 1e3 * pixel_m));
  const double w_largest = job.per_region ? 2 * w0 : w0;
  rep.params["voxel_m"] = w0;
  rep.params["voxel_coarse_m"] = w_largest;
  rep.params["geometry"] = std::string(mode_name);
  rep.params["poses"] = poses->source;
  rep.params["target_error_px"] = job.target_error_px;
  rep.params["camera_gap_deg"] = spacing.max_gap_rad * 180 / std::numbers::pi;
  rep.params["view_distance_m"] = view_distance;
  rep.params["near_distance_m"] = near_distance;
  rep.params["texel_angle_deg"] = delta * 180 / std::numbers::pi;
  rep.params["truncation_m"] = job.truncation_voxels * w0;
  rep.errors["predicted_texel_error_px"] = focal * texel_error_bound(w_largest, delta) / near_distance;
  const size_t max_cells = size_t(4e8);
  if (std::pow(box.sizes().maxCoeff() / w0, 3) > double(max_cells) * 64)
    return fail(fmt::format("voxel {:.3g} m is too small for a {:.3g} m scene (over 2.5e10 cells): choose a larger --voxel",
                            w0, box.sizes().maxCoeff()));

  // Fusion.
  SparseVolume volume(w0, job.truncation_voxels * w0, crop);
  std::vector<DepthObservation> depth_obs;
  if (mode == Geometry::depth || mode == Geometry::both) {
    Progress progress("fuse depth", views.size());
    for (const auto& v : views) {
      if (v.depth.empty()) {
        rep.skipped["views_without_depth"] += 1;
        progress.tick();
        continue;
      }
      depth_obs.push_back({&v.depth, unit, *depth_K, v.world_from_camera * color_from_depth});
    }
    volume.integrate(depth_obs, job.threads, [&] { progress.tick(); });
    progress.done();
    const auto& fs_ = volume.fusion_stats();
    rep.counts["depth_samples"] = double(fs_.depth_samples);
    rep.counts["voxel_updates"] = double(fs_.voxel_updates);
    if (fs_.samples_outside_crop) rep.skipped["depth_samples_outside_object_box"] = double(fs_.samples_outside_crop);
  }
  timer.lap("fusion");
  if (mode == Geometry::hull || mode == Geometry::both) {
    std::vector<SilhouetteObservation> sil;
    for (size_t i = 0; i < views.size(); ++i) sil.push_back({&masks[i], views[i].K, views[i].world_from_camera});
    const HullStats hs = volume.carve_hull(sil, mode == Geometry::both ? depth_obs : std::vector<DepthObservation>{}, box, job.threads);
    rep.counts["hull_voxels"] = double(hs.hull_voxels);
    rep.counts["hull_cells_tested"] = double(hs.cells_tested);
    rep.counts["fuzzy_voxels"] = double(hs.fuzzy_voxels);
    if (mode == Geometry::both) {
      rep.skipped["hull_voxels_free_by_depth"] = double(hs.carved_by_depth);
      rep.skipped["hull_voxels_inside_by_depth"] = double(hs.solid_by_depth);
    }
  }
  timer.lap("hull");

  std::error_code ec;
  fs::create_directories(job.out / "cameras", ec);
  if (ec) return fail("cannot create '" + (job.out / "cameras").string() + "': " + ec.message());
  // The surface octree and its finest crack-free patch mesh (the textured-mesh
  // baseline), built from the volume alone in a task of its own alongside the
  // evidence, the cameras' depth and the facets: its seconds overlap theirs.
  struct OctreePart {
    std::vector<OctreeRecord> records;
    int max_level = 0;
    std::map<std::string, double> counts;
    bool patch_mesh = false;
  };
  std::future<Result<OctreePart>> octree_part = std::async(std::launch::async, [&]() -> Result<OctreePart> {
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
      if (auto st2 = write_ply_mesh(job.out / "patches.ply", patches); !st2) return std::unexpected(st2.error());
      part.patch_mesh = true;
    }
    part.counts["seconds_octree"] = clock.seconds();
    return part;
  });

  // Evidence and the fused surface.
  const auto evidence = volume.evidence(w0 / 4);
  if (evidence.empty()) rep.warnings.push_back("no voxel holds surface evidence: the model has no facets");
  rep.counts["evidence_voxels"] = double(evidence.size());
  rep.counts["active_voxels"] = double(volume.active_voxels());
  rep.skipped["voxels_without_evidence"] = double(volume.active_voxels()) - double(evidence.size());
  rep.counts["volume_bytes"] = double(volume.memory_bytes());
  const Mesh surface = volume.surface_mesh(evidence);
  rep.counts["surface_triangles"] = double(surface.faces.size());
  // Written in a task of its own while the cameras' depth is made.
  std::future<Status> surface_written = std::async(std::launch::async, [&]() -> Status {
    if (surface.faces.empty()) return {};
    return write_ply_mesh(job.out / "surface.ply", surface);
  });
  timer.lap("evidence");

  // Per-camera depth and textures: the fused surface rasterized into every
  // camera (the exact ray test per pixel; see camera_depth.h).
  // The fused surface is wound as OpenVDB meshes it (normals inward): faces
  // turned away from a camera are left out.
  const MeshRasterizer raster(surface, MeshRasterizer::Faces::kInwardWound);
  // The facets' visibility test reads each camera's depth every `stride`
  // pixels, the spacing on the evidence's far side within w/3 (see
  // visibility_stride). Without textures only that grid is drawn.
  std::vector<int> stride(views.size(), 1);
  {
    Eigen::AlignedBox3d box_e;
    for (const auto& e : evidence) box_e.extend(e.centre.cast<double>());
    for (size_t i = 0; i < views.size() && !box_e.isEmpty(); ++i) {
      const Eigen::Isometry3d camera_from_world = views[i].world_from_camera.inverse();
      double far = 0;
      for (int c = 0; c < 8; ++c) far = std::max(far, (camera_from_world * box_e.corner(Eigen::AlignedBox3d::CornerType(c))).z());
      stride[i] = visibility_stride(w0, far, views[i].K);
    }
    rep.counts["visibility_stride_max"] = double(*std::max_element(stride.begin(), stride.end()));
  }
  raster.prepare(job.textures ? views.front().K : visibility_grid(views.front().K, stride.front()), job.threads);
  std::atomic<size_t> drawn{0}, culled{0}, back{0}, back_runs{0}, tested{0};
  auto camera_depth = [&](const Intrinsics& K, const Eigen::Isometry3d& world_from_camera) {
    MeshRasterizer::Stats rs;
    ImageF d = raster.distance_image(K, world_from_camera, &rs);
    drawn += rs.triangles_drawn, culled += rs.triangles_culled, back += rs.back_faces, tested += rs.pixels_tested;
    back_runs += rs.back_faces_in_runs;
    return d;
  };
  Model model;
  model.voxel_size_m = w0;
  std::vector<ImageF> distance(views.size());
  for (const View& v : views) {
    ModelCamera mc;
    mc.intrinsics = v.K;
    mc.world_from_camera = v.world_from_camera;
    mc.session_frame = v.frame;
    if (job.textures) mc.texture = "cameras/" + frame_file_name(v.frame, "exr");
    model.cameras.push_back(mc);
  }
  if (job.textures) {
    // Every camera's depth goes into its texture; without textures each one
    // is made when the facets' visibility test comes to it.
    Progress progress("camera depth", views.size());
    std::mutex progress_mutex;
    parallel_for(int(views.size()), worker_count(job.threads), [&](int i) {
      distance[size_t(i)] = camera_depth(views[size_t(i)].K, views[size_t(i)].world_from_camera);
      const std::lock_guard<std::mutex> lock(progress_mutex);
      progress.tick();
    });
    progress.done();
  }
  timer.lap("camera_depth");
  if (job.textures) {
    // Colour + alpha (geometry hit) + distance, one OpenEXR per camera, written in parallel.
    std::vector<Status> written(views.size());
    parallel_for(int(views.size()), worker_count(job.threads), [&](int i) {
      const View& v = views[size_t(i)];
      RgbazImage t{ImageU8(v.K.width, v.K.height, 4), distance[size_t(i)]};
      const size_t ch = size_t(v.color.channels);
      for (size_t p = 0; p < t.rgba.pixels(); ++p) {
        for (size_t k = 0; k < 3; ++k) t.rgba.data[p * 4 + k] = v.color.data[p * ch + std::min(k, ch - 1)];
        t.rgba.data[p * 4 + 3] = t.distance.data[p] > 0 ? 255 : 0;
      }
      written[size_t(i)] = write_rgbaz(job.out / model.cameras[size_t(i)].texture, t);
    });
    for (const auto& st : written)
      if (!st) return std::unexpected(st.error());
  } else {
    rep.skipped["camera_textures_not_written"] = double(views.size());
  }
  timer.lap("textures");

  // Facets.
  std::vector<FacetCamera> fc;
  for (size_t i = 0; i < views.size(); ++i) {
    FacetCamera c{views[i].K, views[i].world_from_camera, job.textures ? &distance[i] : nullptr, {}, stride[i]};
    if (!job.textures) {
      const Intrinsics G = visibility_grid(views[i].K, stride[i]);
      c.distance_at = [&, i, G] { return camera_depth(G, views[i].world_from_camera); };
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
  rep.counts["camera_depth_triangles_drawn"] = double(drawn);
  rep.counts["camera_depth_pixels_tested"] = double(tested);
  rep.skipped["facets_seen_by_no_camera"] = double(st.unseen);
  rep.skipped["facet_camera_pairs_occluded"] = double(st.occluded);
  rep.skipped["facet_camera_pairs_outside_image"] = double(st.outside_image);
  rep.skipped["camera_depth_triangles_outside_view"] = double(culled);
  rep.skipped["camera_depth_back_faces"] = double(back);
  rep.skipped["camera_depth_back_faces_in_whole_runs"] = double(back_runs);
  const MeshRasterizer::RayTiles tiles = raster.ray_tiles();
  rep.counts["camera_depth_ray_tiles"] = double(tiles.made);
  rep.skipped["camera_depth_ray_tiles_not_needed"] = double(tiles.total - tiles.made);
  timer.lap("facets");

  Eigen::AlignedBox3d bounds;
  for (const auto& f : model.facets) {
    const Eigen::Vector3d c(f.center[0], f.center[1], f.center[2]);
    bounds.extend(c - Eigen::Vector3d::Constant(f.size));
    bounds.extend(c + Eigen::Vector3d::Constant(f.size));
  }
  if (bounds.isEmpty()) bounds = Eigen::AlignedBox3d(centre, centre);
  model.bounds = bounds;
  {
    Result<OctreePart> part = octree_part.get();
    if (!part) return std::unexpected(part.error());
    model.octree = std::move(part->records);
    model.octree_max_level = part->max_level;
    for (const auto& [k, v] : part->counts) rep.counts[k] = v;
    if (part->patch_mesh) model.patch_mesh = "patches.ply";
  }
  timer.lap("octree_wait");
  if (auto st2 = surface_written.get(); !st2) return std::unexpected(st2.error());
  if (!surface.faces.empty()) model.surface_mesh = "surface.ply";
  if (auto st2 = save_model(job.out, model); !st2) return std::unexpected(st2.error());
  timer.lap("write");
  rep.counts["model_bytes"] = double(model.facets.size() * sizeof(FacetRecord) + model.facet_cameras.size() * 4);
  rep.seconds = total.seconds();

  // The synthetic rig knows the truth: report the model's error against it
  // (not counted in the build seconds).
  const fs::path truth_mesh = s.root / "ground_truth" / "geometry.ply";
  if (fs::exists(truth_mesh)) {
    auto mesh = read_ply_mesh(truth_mesh);
    if (!mesh) return std::unexpected(mesh.error());
    std::vector<FacetRecord> solid;
    for (const auto& f : model.facets)
      if (f.size <= w0 * 1.01) solid.push_back(f);
    const SurfaceDistance distance_to_truth(*mesh, w0 / 5);
    const SurfaceError all = distance_to_truth.error(model.facets);
    const SurfaceError fine = distance_to_truth.error(solid);
    rep.errors["facets_within_w_fraction"] = all.within_size;
    rep.errors["facet_distance_median_m"] = all.median_m;
    rep.errors["facet_distance_p99_m"] = all.p99_m;
    rep.errors["fine_facets_within_w_fraction"] = fine.within_size;
    if (job.textures) {
      auto de = camera_depth_error(model, job.out, s.root);
      if (!de) return std::unexpected(de.error());
      rep.errors["camera_depth_median_m"] = de->median_m;
      rep.errors["camera_depth_p90_m"] = de->p90_m;
      rep.errors["camera_depth_missing_fraction"] = de->missing;
    }
    if (fs::exists(s.root / "ground_truth" / "strands.ply")) {
      auto sc = strand_coverage(model, s.root);
      if (!sc) return std::unexpected(sc.error());
      rep.errors["strand_pixels_covered_fraction"] = sc->covered;
      rep.errors["facet_pixels_on_background_fraction"] = sc->background;
    }
    timer.lap("truth_check");
  }
  return rep;
}

}  // namespace s2r
