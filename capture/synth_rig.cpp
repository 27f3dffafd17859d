// The rig renders through the reference ray tracer (trace/raytracer.h): the
// same Embree tracer as `s2r raytrace`, with the rig's strands as round
// curves, its printed patterns as procedural albedo and its lamp as a
// directional light without shadows that turns with the lab.
#include "capture/synth_rig.h"
#include "core/angles.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "capture/synth_scenes.h"
#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/json_fields.h"
#include "core/paths.h"
#include "core/progress.h"
#include "trace/raytracer.h"

namespace s2r {
namespace fs = std::filesystem;
using Eigen::Vector3d;
using Eigen::Vector3f;

namespace {


uint64_t mix(uint64_t x) {  // splitmix64 finaliser
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}
uint64_t hash(uint64_t a, uint64_t b, uint64_t c = 0, uint64_t d = 0) {
  return mix(a ^ mix(b ^ mix(c ^ mix(d))));
}
double uniform(uint64_t h) { return (double(h >> 11) + 0.5) * (1.0 / 9007199254740992.0); }
double gaussian(uint64_t h) {  // Box-Muller from one hash
  const double u1 = uniform(mix(h)), u2 = uniform(mix(h ^ 0xabcdefULL));
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2 * std::numbers::pi * u2);
}

Vector3f patch_albedo(const Vector3f& p, float cell) {
  const int64_t ix = static_cast<int64_t>(std::floor(p.x() / cell));
  const int64_t iy = static_cast<int64_t>(std::floor(p.y() / cell));
  const int64_t iz = static_cast<int64_t>(std::floor(p.z() / cell));
  const uint64_t h = hash(uint64_t(ix), uint64_t(iy), uint64_t(iz), 17);
  Vector3f c(0.2f + 0.7f * float(uniform(h)), 0.2f + 0.7f * float(uniform(mix(h + 1))),
             0.2f + 0.7f * float(uniform(mix(h + 2))));
  const float stripes =
      0.85f + 0.15f * std::sin(2 * std::numbers::pi_v<float> * (p.x() + 0.7f * p.y() + 0.4f * p.z()) /
                               (cell / 3));
  return c * stripes;
}

// Lambert with an ambient share: albedo (ambient + direct max(0, n.l)),
// under one light of intensity kLight (RtMaterial: local = k_a base +
// I base n.l with base = kd albedo).
constexpr float kLight = 0.7f;
RtMaterial lambert(float ambient, float direct) {
  RtMaterial m;
  const float kd = direct / kLight;
  m.diffuse = Vector3f::Constant(kd);
  m.ambient = ambient / kd;
  m.specular = Vector3f::Zero();
  m.shininess = 0;
  return m;
}

}  // namespace

Status SynthOptions::validate() const {
  if (views < 1 || views > 3600) return fail(ErrorCode::invalid, "views: must be in 1..3600");
  if (width < 16 || width > 8192) return fail(ErrorCode::invalid, "width: must be within 16..8192 pixels");
  if (height < 16 || height > 8192) return fail(ErrorCode::invalid, "height: must be within 16..8192 pixels");
  if (spp != 1 && spp != 4) return fail(ErrorCode::invalid, "spp: must be 1 or 4");
  if (!(depth_noise_k >= 0)) return fail(ErrorCode::invalid, "depth_noise_k: must be >= 0");
  if (!(depth_unit_m > 0)) return fail(ErrorCode::invalid, "depth_unit_m: must be > 0");
  if (!(dropout >= 0 && dropout <= 1)) return fail(ErrorCode::invalid, "dropout: must be in [0, 1]");
  if (!(grazing_deg > 0 && grazing_deg <= 90)) return fail(ErrorCode::invalid, "grazing_deg: must be in (0, 90]");
  if (!(exposure > 0 && exposure < 1000)) return fail(ErrorCode::invalid, "exposure: must be in (0, 1000)");
  if (!(color_noise >= 0)) return fail(ErrorCode::invalid, "color_noise: must be >= 0");
  return {};
}

struct SynthRig::Impl {
  SynthOptions opt;
  synth::Scene scene;
  Intrinsics color_K, depth_K;
  Eigen::Isometry3d color_from_depth = Eigen::Isometry3d::Identity();
  std::unique_ptr<RayTracer> tracer;
  // Ray directions (camera frame, z = 1) per pixel: centre, colour sub-samples, depth neighbours.
  std::vector<Vector3f> color_centre, color_sub, depth_centre, depth_nb;
  Eigen::Isometry3d board_from_world = Eigen::Isometry3d::Identity();
  Eigen::Matrix3d world_from_board_linear = Eigen::Matrix3d::Identity();

  double true_angle_deg(int view) const { return view * 360.0 / opt.views - view * opt.table_error_deg; }
  Eigen::Isometry3d world_from_camera(int view) const { return world_from_camera_at(true_angle_deg(view)); }
  Eigen::Isometry3d world_from_camera_at(double angle_deg) const {
    const double a = angle_deg * kDeg;
    const double sign = scene.layout == Layout::kObjectCentre ? -1.0 : 1.0;
    Eigen::Isometry3d r = Eigen::Isometry3d::Identity();
    r.linear() = Eigen::AngleAxisd(sign * a, Vector3d::UnitZ()).toRotationMatrix();
    if (scene.camera_wobble_deg == 0) return r * scene.table_from_camera;
    // Elevation swing about the target, then a roll about the optical axis.
    const double w = scene.camera_wobble_deg * kDeg;
    const Eigen::Isometry3d swing = Eigen::Translation3d(scene.wobble_centre) *
                                    Eigen::AngleAxisd(w * std::sin(3 * a), Vector3d::UnitX()) *
                                    Eigen::Translation3d(-scene.wobble_centre);
    const Eigen::Isometry3d roll(Eigen::AngleAxisd(0.75 * w * std::cos(2 * a), Vector3d::UnitZ()));
    return r * swing * scene.table_from_camera * roll;
  }

  Vector3d light_world_at(double angle_deg) const {
    if (scene.layout == Layout::kCameraCentre) return scene.light_dir_lab;
    const double a = angle_deg * kDeg;
    return Eigen::AngleAxisd(-a, Vector3d::UnitZ()) * scene.light_dir_lab;
  }

  std::vector<PointLight> lights_at(double angle_deg) const {
    PointLight l;
    l.position = light_world_at(angle_deg);
    l.intensity = Vector3f::Constant(kLight);
    l.directional = true;
    l.shadows = false;
    return {l};
  }

  // The procedural albedo of a surface's print.
  std::function<Vector3f(const Vector3f&, const Vector3f&)> albedo(synth::Texture texture) const {
    switch (texture) {
      case synth::Texture::kChessboard: {
        const Eigen::Isometry3d bw = board_from_world;
        const Vector3f board_z = world_from_board_linear.col(2).cast<float>();
        const double square = scene.board_square_m;
        const int nx = scene.board_squares_x, ny = scene.board_squares_y;
        return [bw, board_z, square, nx, ny](const Vector3f& p, const Vector3f& dir) -> Vector3f {
          const Eigen::Vector3d b = bw * p.cast<double>();
          // The print is on the -z side (OpenCV board frames: z points away from the camera).
          const bool front = board_z.dot(dir) > 0;
          const int cx = static_cast<int>(std::floor(b.x() / square)) + 1;
          const int cy = static_cast<int>(std::floor(b.y() / square)) + 1;
          const bool inside = cx >= 0 && cy >= 0 && cx < nx && cy < ny;
          return Vector3f::Constant(front && inside && (cx + cy) % 2 == 0 ? 0.04f : 0.85f);
        };
      }
      case synth::Texture::kPatches: return [](const Vector3f& p, const Vector3f&) { return patch_albedo(p, 0.012f); };
      case synth::Texture::kWalls: return [](const Vector3f& p, const Vector3f&) { return patch_albedo(p, 0.3f); };
      default: return [](const Vector3f&, const Vector3f&) { return Vector3f(0.55f, 0.5f, 0.45f); };
    }
  }

  // The scene for the tracer: every surface and the strands, lit per frame.
  RtScene tracer_scene() const {
    RtScene rs;
    rs.background = Vector3f::Constant(0.03f);
    for (size_t i = 0; i < scene.surfaces.size(); ++i) {
      const auto& surf = scene.surfaces[i];
      RtObject o;
      o.name = scene.name + " surface " + std::to_string(i);
      o.mesh.vertices = surf.mesh.vertices;
      o.mesh.normals = surf.mesh.normals;
      o.mesh.levels = {surf.mesh.faces};
      // The board is lit more softly (a matte print).
      o.material = surf.texture == synth::Texture::kChessboard ? lambert(0.55f, 0.45f) : lambert(0.3f, 0.7f);
      o.material.albedo = albedo(surf.texture);
      rs.objects.push_back(std::move(o));
    }
    if (!scene.strands.segments.empty()) {
      RtCurves c;
      c.name = scene.name + " strands";
      c.points = scene.strands.points;
      c.segments = scene.strands.segments;
      c.colors = scene.strands.colors;
      c.material = lambert(0.3f, 0.7f);
      rs.curves.push_back(std::move(c));
    }
    return rs;
  }

  RtHit trace(const Vector3f& org, const Vector3f& dir) const {
    return tracer->intersect(org, dir, static_cast<float>(scene.far_m));
  }
  static synth::Label label(const RtHit& h) { return h.curves >= 0 ? synth::kStrand : synth::kSurface; }
};

SynthRig::SynthRig(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
SynthRig::~SynthRig() = default;

Result<std::unique_ptr<SynthRig>> SynthRig::create(const SynthOptions& options) {
  if (auto st = options.validate(); !st) return std::unexpected(st.error());
  auto impl = std::make_unique<Impl>();
  impl->opt = options;
  const fs::path data = options.data_dir.empty() ? data_dir() : options.data_dir;
  auto scene = synth::make_scene(options.scene, options.seed, data);
  if (!scene) return std::unexpected(scene.error());
  impl->scene = std::move(*scene);
  impl->board_from_world = impl->scene.world_from_board.inverse();
  impl->world_from_board_linear = impl->scene.world_from_board.linear();

  const double s = options.width / 640.0;
  const int w = options.width, h = options.height;
  Intrinsics& c = impl->color_K;
  c.width = w; c.height = h;
  c.fx = 600.0 * s; c.fy = 601.5 * s;
  c.cx = (w - 1) / 2.0 + 3.1 * s; c.cy = (h - 1) / 2.0 - 2.3 * s;
  c.dist = {-0.12, 0.05, 0.0008, -0.0005, 0.0};
  Intrinsics& d = impl->depth_K;
  d.width = w; d.height = h;
  d.fx = 583.0 * s; d.fy = 583.0 * s;
  d.cx = (w - 1) / 2.0 - 1.5 * s; d.cy = (h - 1) / 2.0 + 1.2 * s;
  impl->color_from_depth.linear() =
      (Eigen::AngleAxisd(0.4 * kDeg, Vector3d::UnitY()) * Eigen::AngleAxisd(-0.2 * kDeg, Vector3d::UnitX()))
          .toRotationMatrix();
  impl->color_from_depth.translation() = Vector3d(0.025, 0.001, -0.0005);

  // Ray tables.
  auto table = [&](const Intrinsics& K, std::vector<Vector3f>& out,
                   const std::vector<Eigen::Vector2d>& offsets) -> Status {
    out.resize(static_cast<size_t>(w) * h * offsets.size());
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (size_t k = 0; k < offsets.size(); ++k) {
          auto r = K.ray(Eigen::Vector2d(x, y) + offsets[k]);
          if (!r) return fail("lens model does not invert at pixel " + std::to_string(x) + "," + std::to_string(y));
          out[(static_cast<size_t>(y) * w + x) * offsets.size() + k] = r->cast<float>();
        }
    return {};
  };
  std::vector<Eigen::Vector2d> sub = options.spp == 1
      ? std::vector<Eigen::Vector2d>{{0, 0}}
      : std::vector<Eigen::Vector2d>{{-0.25, -0.25}, {0.25, -0.25}, {-0.25, 0.25}, {0.25, 0.25}};
  for (auto st : {table(c, impl->color_centre, {{0, 0}}), table(c, impl->color_sub, sub),
                  table(d, impl->depth_centre, {{0, 0}}),
                  table(d, impl->depth_nb, {{-0.75, 0}, {0.75, 0}, {0, -0.75}, {0, 0.75}})})
    if (!st) return std::unexpected(st.error());

  // The reference tracer over the scene.
  auto tracer = RayTracer::create(impl->tracer_scene());
  if (!tracer) return std::unexpected(tracer.error());
  impl->tracer = std::move(*tracer);
  return std::unique_ptr<SynthRig>(new SynthRig(std::move(impl)));
}

const SynthOptions& SynthRig::options() const { return impl_->opt; }
Layout SynthRig::layout() const { return impl_->scene.layout; }
const Intrinsics& SynthRig::color_intrinsics() const { return impl_->color_K; }
const Intrinsics& SynthRig::depth_intrinsics() const { return impl_->depth_K; }
const Eigen::Isometry3d& SynthRig::color_from_depth() const { return impl_->color_from_depth; }
Eigen::Isometry3d SynthRig::world_from_camera(int view) const { return impl_->world_from_camera(view); }
Eigen::Isometry3d SynthRig::world_from_camera_at(double a) const { return impl_->world_from_camera_at(a); }
Eigen::Isometry3d SynthRig::world_from_board() const { return impl_->scene.world_from_board; }
double SynthRig::commanded_angle_deg(int view) const { return view * 360.0 / impl_->opt.views; }
double SynthRig::true_angle_deg(int view) const { return impl_->true_angle_deg(view); }
Vector3d SynthRig::axis_dir_camera() const {
  return impl_->scene.table_from_camera.inverse().linear() * Vector3d::UnitZ();
}
Vector3d SynthRig::axis_point_camera() const {
  return impl_->scene.table_from_camera.inverse() * Vector3d::Zero();
}

SynthView SynthRig::render(int view) const { return render_at(impl_->true_angle_deg(view), uint64_t(view)); }

SynthView SynthRig::render_at(double table_angle_deg, uint64_t noise_key) const {
  const Impl& m = *impl_;
  const uint64_t view = noise_key;
  const int w = m.opt.width, h = m.opt.height;
  const size_t spp = m.color_sub.size() / (static_cast<size_t>(w) * h);
  SynthView out;
  out.color = ImageU8(w, h, 3);
  out.gt_depth_color = ImageF(w, h, 1);
  out.depth = ImageU16(w, h, 1);
  out.gt_depth = ImageF(w, h, 1);
  out.labels = ImageU8(w, h, 1);
  const Eigen::Isometry3f wc = m.world_from_camera_at(table_angle_deg).cast<float>();
  const Eigen::Isometry3f wd = (m.world_from_camera_at(table_angle_deg) * m.color_from_depth).cast<float>();
  const std::vector<PointLight> lights = m.lights_at(table_angle_deg);
  const float cos_grazing = static_cast<float>(std::cos(m.opt.grazing_deg * kDeg));
  const uint64_t seed = m.opt.seed;
  const int threads = m.opt.threads > 0 ? m.opt.threads : omp_get_max_threads();

#pragma omp parallel for schedule(dynamic, 4) num_threads(threads)
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t pix = static_cast<size_t>(y) * w + x;
      // Colour: sub-samples averaged, then gamma, noise, 8 bits.
      const Vector3f oc = wc.translation();
      Vector3f sum = Vector3f::Zero();
      for (size_t k = 0; k < spp; ++k) {
        const Vector3f d = wc.linear() * m.color_sub[pix * spp + k];
        sum += m.tracer->trace(oc.cast<double>(), d.cast<double>(), 1.0, 0, nullptr, &lights);
      }
      sum *= static_cast<float>(m.opt.exposure) / float(spp);
      for (int c = 0; c < 3; ++c) {
        double v = std::pow(std::clamp(double(sum[c]), 0.0, 1.0), 1 / 2.2) * 255.0;
        v += m.opt.color_noise * gaussian(hash(seed, uint64_t(view), pix, 100 + uint64_t(c)));
        out.color.at(x, y, c) = static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L));
      }
      const auto gc = m.trace(oc, wc.linear() * m.color_centre[pix]);
      out.gt_depth_color.at(x, y) = gc.found ? gc.t : 0.f;

      // Depth camera: exact z, label, then the sensor model.
      const Vector3f od = wd.translation();
      const Vector3f dc = wd.linear() * m.depth_centre[pix];
      const auto hc = m.trace(od, dc);
      if (!hc.found) continue;
      out.gt_depth.at(x, y) = hc.t;
      out.labels.at(x, y) = Impl::label(hc);
      bool hole = false;
      for (int k = 0; k < 4 && !hole; ++k) {
        const auto hn = m.trace(od, wd.linear() * m.depth_nb[pix * 4 + k]);
        hole = !hn.found || std::abs(hn.t - hc.t) > 0.02f * hc.t;
      }
      const float cos_inc = std::abs(hc.normal.dot(dc.normalized()));
      hole = hole || cos_inc < cos_grazing;
      hole = hole || (m.opt.dropout > 0 && uniform(hash(seed, uint64_t(view), pix, 200)) < m.opt.dropout);
      if (hole) continue;
      const double z = hc.t + m.opt.depth_noise_k * hc.t * hc.t * gaussian(hash(seed, uint64_t(view), pix, 300));
      const long count = std::lround(z / m.opt.depth_unit_m);
      if (count >= 1 && count <= 65535) out.depth.at(x, y) = static_cast<uint16_t>(count);
    }
  }
  out.rays = static_cast<size_t>(w) * h * (spp + 6);
  return out;
}

Status SynthRig::write_geometry(const fs::path& dir) const {
  Mesh all;
  for (const auto& s : impl_->scene.surfaces) {
    const int base = static_cast<int>(all.vertices.size());
    all.vertices.insert(all.vertices.end(), s.mesh.vertices.begin(), s.mesh.vertices.end());
    for (const auto& f : s.mesh.faces) all.faces.emplace_back(f + Eigen::Vector3i::Constant(base));
  }
  if (auto st = write_ply_mesh(dir / "geometry.ply", all); !st) return st;
  const auto& st = impl_->scene.strands;
  if (st.segments.empty()) return {};
  std::string ply = "ply\nformat ascii 1.0\ncomment strands: round linear curves, radius per vertex\n";
  ply += "element vertex " + std::to_string(st.points.size()) +
         "\nproperty float x\nproperty float y\nproperty float z\nproperty float radius\n";
  ply += "element edge " + std::to_string(st.segments.size()) +
         "\nproperty int vertex1\nproperty int vertex2\nend_header\n";
  char buf[128];
  for (const auto& p : st.points) {
    std::snprintf(buf, sizeof buf, "%.7g %.7g %.7g %.7g\n", p.x(), p.y(), p.z(), p.w());
    ply += buf;
  }
  for (uint32_t s : st.segments) ply += std::to_string(s) + " " + std::to_string(s + 1) + "\n";
  return write_file_atomic(dir / "strands.ply", ply);
}

Result<Report> synth_session(const SynthOptions& options, const fs::path& out) {
  Stopwatch clock;
  auto rig = SynthRig::create(options);
  if (!rig) return std::unexpected(rig.error());
  const SynthRig& r = **rig;

  Session header;
  header.root = out;
  header.name = out.filename().string();
  header.source = "synth:" + options.scene;
  header.layout = r.layout();
  header.color = ColorSensor{"synth", options.scene, "RGB8", r.color_intrinsics(), 10000 * options.exposure, 1};
  DepthSensor ds;
  ds.driver = "synth";
  ds.device = options.scene;
  ds.intrinsics = r.depth_intrinsics();
  ds.unit_m = options.depth_unit_m;
  ds.color_from_depth = r.color_from_depth();
  header.depth = ds;
  header.turntable = TurntableInfo{"synth", "virtual"};
  header.notes.push_back("synthetic turntable rig; exact poses, depth and geometry in ground_truth/");
  auto writer = SessionWriter::create(header);
  if (!writer) return std::unexpected(writer.error());

  const fs::path gt = out / "ground_truth";
  Report rep;
  rep.stage = "synth";
  double sq_err = 0, n_valid = 0, n_holes = 0, n_seen = 0, strand_px = 0, strand_holes = 0;
  size_t rays = 0;
  nlohmann::json frames = nlohmann::json::array();
  Progress progress("synth " + options.scene, static_cast<size_t>(options.views));
  for (int i = 0; i < options.views; ++i) {
    SynthView v = r.render(i);
    rays += v.rays;
    for (size_t p = 0; p < v.depth.pixels(); ++p) {
      if (v.labels.data[p] == 0) continue;
      ++n_seen;
      const bool strand = v.labels.data[p] == synth::kStrand;
      strand_px += strand;
      if (v.depth.data[p] == 0) {
        ++n_holes;
        strand_holes += strand;
        continue;
      }
      const double e = v.depth.data[p] * options.depth_unit_m - v.gt_depth.data[p];
      sq_err += e * e;
      ++n_valid;
    }
    const std::string name = frame_file_name(i, "exr");
    for (auto st : {write_image(gt / "depth_color" / name, v.gt_depth_color),
                    write_image(gt / "depth" / name, v.gt_depth),
                    write_image(gt / "labels" / frame_file_name(i, "png"), v.labels)})
      if (!st) return std::unexpected(st.error());
    Frame f;
    f.index = i;
    f.table_angle_commanded_deg = r.commanded_angle_deg(i);
    f.table_angle_reported_deg = r.commanded_angle_deg(i);
    f.timestamp_ns = int64_t(i) * 2'000'000'000LL;
    f.exposure_us = 10000 * options.exposure;
    if (auto st = writer->add_frame(f, &v.color, &v.depth); !st) return std::unexpected(st.error());
    frames.push_back({{"index", i}, {"table_angle_true_deg", r.true_angle_deg(i)},
                      {"world_from_camera", rigid_to_json(r.world_from_camera(i))},
                      {"world_from_depth", rigid_to_json(r.world_from_camera(i) * r.color_from_depth())}});
    progress.tick();
  }
  progress.done();

  nlohmann::json truth = {
      {"format", "s2r.synth_truth"}, {"version", 1}, {"scene", options.scene},
      {"seed", options.seed},
      {"layout", r.layout() == Layout::kObjectCentre ? "object_centre" : "camera_centre"},
      {"color_intrinsics", intrinsics_to_json(r.color_intrinsics())},
      {"depth_intrinsics", intrinsics_to_json(r.depth_intrinsics())},
      {"color_from_depth", rigid_to_json(r.color_from_depth())},
      {"axis_dir_camera", {r.axis_dir_camera().x(), r.axis_dir_camera().y(), r.axis_dir_camera().z()}},
      {"axis_point_camera", {r.axis_point_camera().x(), r.axis_point_camera().y(), r.axis_point_camera().z()}},
      {"depth_model", {{"noise_k", options.depth_noise_k}, {"unit_m", options.depth_unit_m},
                       {"grazing_deg", options.grazing_deg}, {"dropout", options.dropout},
                       {"discontinuity_rel", 0.02}, {"window_px", 0.75}}},
      {"depth_files", "ground_truth/depth/NNNN.exr: exact z (m) in the depth camera; "
                      "depth_color/: exact z in the colour camera; labels/: 0 none, 1 surface, 2 strand"},
      {"frames", frames}};
  if (options.scene == "board") truth["world_from_board"] = rigid_to_json(r.world_from_board());
  if (auto st = write_file_atomic(gt / "rig.json", dump_json(truth)); !st) return std::unexpected(st.error());
  if (auto st = r.write_geometry(gt); !st) return std::unexpected(st.error());

  rep.seconds = clock.seconds();
  rep.counts["frames"] = options.views;
  rep.counts["rays"] = double(rays);
  rep.counts["pixels_seen"] = n_seen;
  rep.errors["depth_rms_mm"] = n_valid > 0 ? 1000 * std::sqrt(sq_err / n_valid) : 0;
  rep.errors["depth_hole_fraction"] = n_seen > 0 ? n_holes / n_seen : 0;
  if (strand_px > 0) rep.errors["strand_hole_fraction"] = strand_holes / strand_px;
  rep.params["scene"] = options.scene;
  rep.params["views"] = double(options.views);
  rep.params["seed"] = double(options.seed);
  rep.params["width"] = double(options.width);
  rep.params["height"] = double(options.height);
  rep.params["spp"] = double(options.spp);
  rep.params["exposure"] = options.exposure;
  return rep;
}

}  // namespace s2r
