#include "render/raytrace_job.h"

#include <algorithm>
#include <cmath>
#include <cctype>
#include <cstdio>
#include <limits>
#include <map>

#include <spdlog/fmt/fmt.h>

#include "core/image_io.h"
#include "core/image_metrics.h"
#include "core/parallel.h"
#include "core/paths.h"
#include "reconstruct/model.h"

namespace s2r {
namespace fs = std::filesystem;
using Eigen::Vector3d;
using Eigen::Vector3f;
using Eigen::Vector3i;

std::vector<Screen> cave_screens(int pixels, double size) {
  const double h = size / 2;
  std::vector<Screen> s(3);
  s[0] = {"front", {-h, size, -h}, {size, 0, 0}, {0, -size, 0}, pixels, pixels};
  s[1] = {"right", {h, size, -h}, {0, 0, size}, {0, -size, 0}, pixels, pixels};
  s[2] = {"floor", {-h, 0, -h}, {size, 0, 0}, {0, 0, size}, pixels, pixels};
  return s;
}

Vector3d cave_default_eye(double size) { return {0, size / 2, 0}; }

ImageU8 unfold_cave(const std::vector<ImageU8>& walls) {
  if (walls.size() != 3 || walls[0].empty()) return {};
  const int n = walls[0].width;
  ImageU8 out(2 * n, 2 * n, 3, 40);
  const int at[3][2] = {{0, 0}, {n, 0}, {0, n}};
  for (int w = 0; w < 3; ++w) {
    if (walls[w].width != n || walls[w].height != n) return {};
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x)
        for (int c = 0; c < 3; ++c) out.at(at[w][0] + x, at[w][1] + y, c) = walls[w].at(x, y, std::min(c, walls[w].channels - 1));
  }
  return out;
}


Result<RtScene> seed_scene(const Mesh& base, const SeedSceneOptions& o) {
  if (o.scene < 'A' || o.scene > 'D') return fail(fmt::format("unknown scene '{}' (choose A, B, C or D)", o.scene));
  auto mesh = lod_mesh(base, o.n_max, o.n_min, o.levels);
  if (!mesh) return std::unexpected(mesh.error());
  // Stand the object on y = 0, centred on the y axis, 1 m tall.
  const Eigen::AlignedBox3f b = base.bounds();
  const float height = b.sizes().y() > 0 ? b.sizes().y() : b.sizes().maxCoeff();
  const Vector3f foot(b.center().x(), b.min().y(), b.center().z());
  for (auto& v : mesh->vertices) v = (v - foot) / height;
  const bool mirrors = o.scene == 'A' || o.scene == 'C';
  const bool spread = o.scene == 'A' || o.scene == 'B';
  // Where each object stands (its foot) and its height: big enough to fill
  // a good part of the screens it is meant for, as in the paper's figures.
  std::vector<std::pair<Vector3d, double>> at;
  if (spread) {
    for (double x : {-1.2, 0.0, 1.2}) at.push_back({{x, 0.5, -2.6}, 1.3});  // front screen
    for (double z : {-1.2, 0.0, 1.2}) at.push_back({{2.6, 0.5, z}, 1.3});   // right screen
    for (double x : {-0.6, 0.6}) at.push_back({{x, 0.0, -0.5}, 0.6});       // floor screen, at the feet
  } else {
    for (double y : {0.2, 1.6})  // two rows of four filling the front screen: on the floor and on a shelf
      for (double x : {-1.5, -0.5, 0.5, 1.5}) at.push_back({{x, y, -2.3}, 1.3});
  }
  const Vector3f hues[8] = {{0.85f, 0.3f, 0.25f}, {0.3f, 0.75f, 0.35f}, {0.3f, 0.45f, 0.85f}, {0.85f, 0.75f, 0.3f},
                            {0.7f, 0.35f, 0.8f},  {0.3f, 0.75f, 0.8f},  {0.9f, 0.55f, 0.3f},  {0.75f, 0.75f, 0.75f}};
  RtScene s;
  const Vector3d eye = cave_default_eye();
  for (size_t i = 0; i < at.size(); ++i) {
    RtObject obj;
    obj.name = fmt::format("{}{}", mirrors ? "mirror" : "diffuse", i);
    obj.mesh = *mesh;
    obj.mesh.colors.clear();
    for (auto& v : obj.mesh.vertices) v *= static_cast<float>(at[i].second);
    const Vector3d& foot_at = at[i].first;
    const double yaw = std::atan2(eye.x() - foot_at.x(), eye.z() - foot_at.z());  // face the eye
    obj.world_from_object = Eigen::Translation3d(foot_at) * Eigen::AngleAxisd(yaw, Vector3d::UnitY());
    if (mirrors) {
      obj.material.diffuse = 0.35f * hues[i];
      obj.material.specular = Vector3f::Constant(0.6f);
      obj.material.shininess = 80;
      obj.material.reflect = 0.7f;
    } else {
      obj.material.diffuse = hues[i];
      obj.material.specular = Vector3f::Constant(0.15f);
      obj.material.shininess = 20;
    }
    s.objects.push_back(std::move(obj));
  }
  s.lights.push_back({Vector3d(1.0, 5.0, 1.0), Vector3f(1.3f, 1.3f, 1.3f)});
  s.background = {0.18f, 0.2f, 0.26f};
  return s;
}

Result<RtObject> model_object(const fs::path& dir, bool surface_mesh, size_t n_min, int levels) {
  auto model = load_model(dir);
  if (!model) return std::unexpected(model.error());
  const auto& rel = surface_mesh ? model->surface_mesh : model->patch_mesh;
  if (!rel) return fail(fmt::format("model '{}' has no {} (reconstructed without it?)", dir.string(),
                                    surface_mesh ? "surface mesh" : "patch mesh"));
  auto mesh = read_ply_mesh(dir / *rel);
  if (!mesh) return std::unexpected(mesh.error());
  mesh->compute_vertex_normals();
  // Colours from the camera that sees each vertex most head-on.
  std::vector<float> best(mesh->vertices.size(), -2.0f);
  mesh->colors.assign(mesh->vertices.size(), Vector3f::Constant(0.5f));
  const float tol = 2.0f * static_cast<float>(model->voxel_size_m);
  size_t textured = 0;
  for (const auto& cam : model->cameras) {
    if (cam.texture.empty()) continue;
    auto tex = read_rgbaz(dir / cam.texture);
    if (!tex) return std::unexpected(tex.error());
    ++textured;
    const Eigen::Isometry3d cam_from_world = cam.world_from_camera.inverse();
    const Vector3d centre = cam.world_from_camera.translation();
    parallel_for(static_cast<int>(mesh->vertices.size()), 0, [&](int i) {
      const Vector3d p = mesh->vertices[i].cast<double>();
      const Vector3d to_cam = centre - p;
      const float facing = static_cast<float>(mesh->normals[i].cast<double>().dot(to_cam.normalized()));
      if (facing <= best[i]) return;
      auto px = cam.intrinsics.project(cam_from_world * p);
      if (!px) return;
      const int x = static_cast<int>(std::floor(px->x())), y = static_cast<int>(std::floor(px->y()));
      if (x < 0 || y < 0 || x >= tex->distance.width || y >= tex->distance.height) return;
      const float d = tex->distance.at(x, y);
      if (!(d > 0) || std::abs(d - static_cast<float>(to_cam.norm())) > tol) return;
      best[i] = facing;
      for (int c = 0; c < 3; ++c) mesh->colors[i][c] = tex->rgba.at(x, y, c) / 255.0f;
    });
  }
  if (textured == 0) return fail("model '" + dir.string() + "' has no camera textures to colour the mesh with");
  auto rt = lod_mesh(*mesh, mesh->faces.size(), std::max<size_t>(1, std::min(n_min, mesh->faces.size())), levels);
  if (!rt) return std::unexpected(rt.error());
  RtObject obj;
  obj.name = surface_mesh ? "surface mesh" : "patch mesh";
  obj.mesh = std::move(*rt);
  obj.material.diffuse = Vector3f::Ones();
  obj.material.specular = Vector3f::Constant(0.05f);
  obj.material.ambient = 0.35f;
  return obj;
}

LayoutRender render_layout(const RayTracer& tracer, const std::vector<Screen>& screens, const Vector3d& eye,
                           const TraceOptions& options) {
  LayoutRender out;
  Stopwatch sw;
  for (const auto& s : screens) {
    out.walls.push_back(tracer.render(s, eye, options));
    out.stats.add(out.walls.back().stats);
  }
  out.seconds = sw.seconds();
  out.stats.seconds = out.seconds;
  return out;
}

double psnr_where(const LayoutRender& test, const LayoutRender& ref, double lo, double hi) {
  // The walls stacked into one picture and one mask, so the error is pooled
  // over every qualifying pixel; core's masked PSNR does the rest.
  const size_t walls = std::min(test.walls.size(), ref.walls.size());
  if (walls == 0) return std::numeric_limits<double>::quiet_NaN();
  const int w = test.walls[0].color.width;
  int h = 0;
  for (size_t i = 0; i < walls; ++i) {
    if (test.walls[i].color.width != w || !test.walls[i].color.same_shape(ref.walls[i].color))
      return std::numeric_limits<double>::quiet_NaN();
    h += test.walls[i].color.height;
  }
  ImageU8 a(w, h, 3), b(w, h, 3), mask(w, h, 1);
  size_t used = 0, at = 0;
  for (size_t i = 0; i < walls; ++i) {
    const ImageU8 ta = to_u8(test.walls[i].color), tb = to_u8(ref.walls[i].color);
    std::copy(ta.data.begin(), ta.data.end(), a.data.begin() + static_cast<std::ptrdiff_t>(at * 3));
    std::copy(tb.data.begin(), tb.data.end(), b.data.begin() + static_cast<std::ptrdiff_t>(at * 3));
    const ImageF& level = test.walls[i].level;
    for (size_t p = 0; p < level.pixels(); ++p) {
      const bool in = level.data[p] >= lo && level.data[p] <= hi;
      mask.data[at + p] = in ? 255 : 0;
      used += in;
    }
    at += level.pixels();
  }
  if (used == 0) return std::numeric_limits<double>::quiet_NaN();
  auto p = psnr(a, b, &mask);
  return p ? *p : std::numeric_limits<double>::quiet_NaN();
}

namespace {

ImageU8 level_picture(const ImageF& level) {
  // Black outside the field, dark to bright through the periphery, white in the centre.
  ImageU8 out(level.width, level.height, 3);
  for (size_t p = 0; p < level.pixels(); ++p) {
    const float l = level.data[p];
    const uint8_t v = static_cast<uint8_t>(std::lround(std::clamp(l, 0.0f, 1.0f) * 255));
    out.data[p * 3] = v;
    out.data[p * 3 + 1] = l >= 1 ? 255 : static_cast<uint8_t>(v * 0.6);
    out.data[p * 3 + 2] = l >= 1 ? 255 : static_cast<uint8_t>(v * 0.3);
  }
  return out;
}

}  // namespace

Status RaytraceJob::validate() const {
  if (out.empty()) return fail(ErrorCode::invalid, "out: an output folder is required");
  if (size < 8 || size > 8192) return fail(ErrorCode::invalid, "size: must be within 8..8192");
  if (reflect_max < 0 || reflect_max > 64) return fail(ErrorCode::invalid, "reflect_max: must be within 0..64");
  if (n_min < 1 || n_min > n_max) return fail(ErrorCode::invalid, "n_min: must be within 1..n_max");
  if (levels < 1 || levels > 32) return fail(ErrorCode::invalid, "levels: must be within 1..32");
  if (eye && !eye->allFinite()) return fail(ErrorCode::invalid, "eye: must be finite");
  if (gaze && (!gaze->allFinite() || gaze->norm() == 0))
    return fail(ErrorCode::invalid, "gaze: must be a finite, non-zero direction");
  if (!mesh.empty() && !model.empty()) return fail(ErrorCode::invalid, "model: give a mesh or a model, not both");
  if (!layout.empty() && layout != "cave" && layout != "view") return fail(ErrorCode::invalid, "layout: must be 'cave' or 'view'");
  if (mesh.empty() && model.empty() && scene.size() != 1) return fail(ErrorCode::invalid, "scene: must be A, B, C or D");
  return {};
}

namespace {

// The scene to trace: one of the paper's CAVE scenes, a model's mesh, or a PLY.
Result<RtScene> raytrace_scene(const RaytraceJob& job, Report& rep) {
  RtScene scene;
  if (job.mesh.empty() && job.model.empty()) {
    const fs::path data = job.data_dir.empty() ? data_dir() : job.data_dir;
    const fs::path ply = data / "stanford_bunny" / "bun_zipper.ply";
    auto bunny = read_ply_mesh(ply);
    if (!bunny) return fail("the CAVE scenes need the Stanford bunny: " + bunny.error().message);
    SeedSceneOptions so;
    so.scene = static_cast<char>(std::toupper(job.scene[0]));
    so.n_max = job.n_max;
    so.n_min = job.n_min;
    so.levels = job.levels;
    auto s = seed_scene(*bunny, so);
    if (!s) return std::unexpected(s.error());
    rep.params["scene"] = std::string(1, so.scene);
    return std::move(*s);
  }
  if (!job.model.empty()) {
    auto obj = model_object(job.model, job.surface_mesh, job.n_min, job.levels);
    if (!obj) return std::unexpected(obj.error());
    scene.objects.push_back(std::move(*obj));
    rep.params["model"] = job.model.string();
    return scene;
  }
  auto mesh = read_ply_mesh(job.mesh);
  if (!mesh) return std::unexpected(mesh.error());
  auto rt = lod_mesh(*mesh, std::min(job.n_max, mesh->faces.size()),
                     std::min(job.n_min, std::min(job.n_max, mesh->faces.size())), job.levels);
  if (!rt) return std::unexpected(rt.error());
  RtObject obj;
  obj.name = job.mesh.filename().string();
  obj.mesh = std::move(*rt);
  scene.objects.push_back(std::move(obj));
  rep.params["mesh"] = job.mesh.string();
  return scene;
}

// Where the eye is, what it looks at, and the screens it sees.
struct EyePlacement {
  std::vector<Screen> screens;
  Vector3d eye;
  EyeFrame frame;
};

// The CAVE's screens around the eye, or one pinhole view of the object (with
// a lamp above the eye when the scene has none).
Result<EyePlacement> place_eye(const RaytraceJob& job, const std::string& layout, RtScene& scene) {
  EyePlacement p;
  Vector3d gaze = job.gaze.value_or(Vector3d(0, 0, -1));
  if (layout == "cave") {
    p.eye = job.eye.value_or(cave_default_eye());
    p.screens = cave_screens(job.size);
  } else {
    Eigen::AlignedBox3f box;
    for (const auto& o : scene.objects)
      for (const auto& v : o.mesh.vertices) box.extend((o.world_from_object.cast<float>() * v));
    const Vector3d centre = box.center().cast<double>();
    const double radius = std::max(1e-6, 0.5 * static_cast<double>(box.sizes().norm()));
    p.eye = job.eye.value_or(centre + Vector3d(0.35, 0.35, 1.0).normalized() * radius * 2.6);
    // The view looks along the gaze when one is given, else at the object.
    const Vector3d forward = job.gaze ? job.gaze->normalized() : Vector3d((centre - p.eye).normalized());
    if (!job.gaze) gaze = forward;
    p.screens = {Screen::pinhole(p.eye, forward, Vector3d::UnitY(), 45, job.size, job.size * 3 / 4)};
    if (scene.lights.empty()) scene.lights.push_back({p.eye + Vector3d(0, radius * 2, 0), Eigen::Vector3f::Ones()});
  }
  if (!gaze.allFinite()) return fail(ErrorCode::invalid, "gaze: must be finite");
  for (const auto& s : p.screens)
    if (auto st = s.validate(); !st) return std::unexpected(st.error());
  auto frame = EyeFrame::look(gaze);
  if (!frame) return fail("raytrace: " + frame.error().message);
  p.frame = *frame;
  return p;
}

// One PNG per screen (with its level picture under field LOD), and the CAVE unfolded.
Status write_walls(const RaytraceJob& job, const std::string& layout, const std::vector<Screen>& screens,
                   const LayoutRender& main) {
  std::error_code ec;
  fs::create_directories(job.out, ec);
  std::vector<ImageU8> walls;
  for (size_t i = 0; i < screens.size(); ++i) {
    walls.push_back(to_u8(main.walls[i].color));
    if (auto st = write_image(job.out / (screens[i].name + ".png"), walls.back()); !st) return st;
    if (job.field_lod)
      if (auto st = write_image(job.out / ("level_" + screens[i].name + ".png"), level_picture(main.walls[i].level)); !st)
        return st;
  }
  if (layout == "cave") return write_image(job.out / "cave.png", unfold_cave(walls));
  return {};
}

void report_trace(const RayTracer& rt, const LayoutRender& main, Report& rep) {
  const TraceStats& s = main.stats;
  rep.counts["pixels"] = static_cast<double>(s.pixels);
  rep.counts["primary_rays"] = static_cast<double>(s.primary);
  rep.counts["secondary_rays"] = static_cast<double>(s.secondary);
  rep.counts["shadow_rays"] = static_cast<double>(s.shadow);
  rep.counts["central_pixels"] = static_cast<double>(s.central);
  rep.counts["total_internal_reflections"] = static_cast<double>(s.total_internal);
  rep.counts["top_level_scenes"] = static_cast<double>(rt.top_scenes());
  rep.counts["render_seconds"] = main.seconds;
  rep.counts["bvh_build_seconds"] = rt.build_seconds();
  rep.skipped["pixels_outside_visual_field"] = static_cast<double>(s.outside_field);
  rep.skipped["branches_beyond_reflect_budget"] = static_cast<double>(s.depth_cut);
  size_t coarser = 0;
  for (int q = 1; q < RayTracer::kQuanta; ++q)
    if (rt.detail_for(static_cast<double>(q) / RayTracer::kQuanta) != rt.detail_for(1.0)) coarser += s.rays_per_quantum[q];
  rep.skipped["primary_rays_on_coarser_meshes"] = static_cast<double>(coarser);
}

// The same view at full detail: the time ratio and the PSNR inside the
// central field and over all pixels.
Status compare_with_full(const RaytraceJob& job, const RayTracer& rt, const EyePlacement& p, const TraceOptions& opt,
                         const LayoutRender& main, RaytraceSummary& sum) {
  Report& rep = sum.report;
  TraceOptions full = opt;
  full.field_lod = false;
  const LayoutRender ref = render_layout(rt, p.screens, p.eye, full);
  for (size_t i = 0; i < p.screens.size(); ++i)
    if (auto st = write_image(job.out / ("full_" + p.screens[i].name + ".png"), to_u8(ref.walls[i].color)); !st) return st;
  const double central = psnr_where(main, ref, 1.0, 1.0), all = psnr_where(main, ref, 0.0, 1.0);
  sum.psnr_central_field_db = central, sum.psnr_all_pixels_db = all;
  sum.time_ratio_lod_over_full = main.seconds / std::max(1e-9, ref.seconds);
  // JSON has no infinity: identical images are reported as 100 dB and flagged.
  rep.errors["psnr_central_field_db"] = std::isinf(central) ? 100.0 : central;
  rep.errors["psnr_all_pixels_db"] = std::isinf(all) ? 100.0 : all;
  rep.params["central_field_identical"] = std::isinf(central);
  rep.counts["full_render_seconds"] = ref.seconds;
  rep.errors["time_ratio_lod_over_full"] = main.seconds / std::max(1e-9, ref.seconds);
  if (!job.quiet)
    std::fprintf(stderr, "raytrace: LOD %.3f s, full %.3f s (ratio %.3f); PSNR in the central field %s, all pixels %.2f dB\n",
                 main.seconds, ref.seconds, main.seconds / std::max(1e-9, ref.seconds),
                 std::isinf(central) ? "identical" : fmt::format("{:.2f} dB", central).c_str(), all);
  return {};
}

}  // namespace

// The scene, the eye and its screens, the tracer; one render (after an
// untimed one when comparing), its images and counts; the full-detail peer.
Result<RaytraceSummary> run_raytrace_job(const RaytraceJob& job) {
  Stopwatch total;
  RaytraceSummary sum;
  Report& rep = sum.report;
  rep.stage = "raytrace";
  if (auto st = job.validate(); !st) return std::unexpected(st.error());
  const bool seed = job.mesh.empty() && job.model.empty();
  const std::string layout = job.layout.empty() ? (seed ? "cave" : "view") : job.layout;
  auto scene = raytrace_scene(job, rep);
  if (!scene) return std::unexpected(scene.error());
  auto placed = place_eye(job, layout, *scene);
  if (!placed) return std::unexpected(placed.error());
  const EyePlacement& p = *placed;

  size_t triangles_max = 0, triangles_min = 0;
  for (const auto& o : scene->objects) triangles_max += o.mesh.triangles(0), triangles_min += o.mesh.levels.back().size();
  auto tracer = RayTracer::create(std::move(*scene));
  if (!tracer) return std::unexpected(tracer.error());
  const RayTracer& rt = **tracer;
  TraceOptions opt;
  opt.reflect_max = job.reflect_max;
  opt.field_lod = job.field_lod;
  opt.gaze = p.frame;
  opt.threads = job.threads;
  if (!job.quiet)
    std::fprintf(stderr, "raytrace: %zu screens of %dx%d, %s\n", p.screens.size(), p.screens[0].width, p.screens[0].height,
                 job.field_lod ? "visual-field LOD" : "full detail");
  // With a comparison to make, one untimed render first: the first pass pays
  // for page faults and cold caches, which would bias the ratio.
  if (job.compare_full && job.field_lod) render_layout(rt, p.screens, p.eye, opt);
  const LayoutRender main = render_layout(rt, p.screens, p.eye, opt);
  if (auto st = write_walls(job, layout, p.screens, main); !st) return std::unexpected(st.error());
  report_trace(rt, main, rep);
  sum.layout = layout;
  sum.trace = main.stats;
  sum.render_seconds = main.seconds, sum.bvh_build_seconds = rt.build_seconds();
  sum.triangles_full_detail = triangles_max, sum.triangles_coarsest = triangles_min;
  rep.counts["triangles_full_detail"] = static_cast<double>(triangles_max);
  rep.counts["triangles_coarsest"] = static_cast<double>(triangles_min);
  rep.params["layout"] = layout;
  rep.params["eye"] = fmt::format("{},{},{}", p.eye.x(), p.eye.y(), p.eye.z());
  rep.params["gaze"] = fmt::format("{:.4f},{:.4f},{:.4f}", p.frame.forward.x(), p.frame.forward.y(), p.frame.forward.z());
  rep.params["reflect_max"] = static_cast<double>(job.reflect_max);
  rep.params["field_lod"] = job.field_lod;
  if (job.compare_full && job.field_lod)
    if (auto st = compare_with_full(job, rt, p, opt, main, sum); !st) return std::unexpected(st.error());
  sum.seconds = rep.seconds = total.seconds();
  return sum;
}

}  // namespace s2r
