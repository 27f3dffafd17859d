#include "render/model_eval.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <set>

#include "capture/session.h"
#include "calibrate/calibration.h"
#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/image_metrics.h"
#include "core/json_fields.h"
#include "core/progress.h"
#include "core/sweep.h"
#include "reconstruct/fusion.h"
#include "render/gl_context.h"
#include "render/viewer.h"

namespace s2r {
namespace fs = std::filesystem;

Result<ViewCamera> load_view_file(const fs::path& path) {
  auto j = parse_json_file(path);
  if (!j) return std::unexpected(j.error());
  try {
    FieldReader doc(*j, path.filename().string());
    check_format_header(doc, "s2r.view", 1);
    ViewCamera v;
    v.K = intrinsics_from(doc.at("intrinsics"));
    v.world_from_camera = doc.rigid("world_from_camera");
    return v;
  } catch (const FormatError& e) {
    return fail(path.string() + ": " + e.what());
  }
}

Status save_view_file(const fs::path& path, const ViewCamera& v) {
  nlohmann::json j;
  j["format"] = "s2r.view";
  j["version"] = 1;
  j["intrinsics"] = intrinsics_to_json(v.K);
  j["world_from_camera"] = rigid_to_json(v.world_from_camera);
  return write_file_atomic(path, dump_json(j));
}

Result<SessionCameras> SessionCameras::load(const FrameSource& src) {
  SessionCameras c;
  auto s = load_session(src.session);
  if (!s) return std::unexpected(s.error());
  c.session = std::move(*s);
  auto poses = resolve_frame_poses(c.session, src.poses, src.calibration);
  if (!poses) return std::unexpected(poses.error());
  c.poses = std::move(*poses);
  if (!src.calibration.empty()) {
    auto cal = load_calibration(src.calibration);
    if (!cal) return std::unexpected(cal.error());
    c.calibration = std::move(*cal);
  }
  return c;
}

Result<ViewCamera> SessionCameras::view(int frame) const {
  if (frame < 0 || size_t(frame) >= session.frames.size())
    return fail(fmt::format("frame {}: the session has frames 0..{}", frame, int(session.frames.size()) - 1));
  if (!poses.world_from_camera[size_t(frame)]) return fail(fmt::format("frame {} has no pose ({})", frame, poses.source));
  ViewCamera v;
  v.world_from_camera = *poses.world_from_camera[size_t(frame)];
  const auto K = resolve_color_intrinsics(session, session.frames[size_t(frame)], calibration ? &*calibration : nullptr);
  if (!K) return fail(fmt::format("frame {} has no colour intrinsics", frame));
  v.K = *K;
  return v;
}

Result<ViewCamera> frame_view(const Model& model, const FrameSource& src, int frame, bool* own_capture) {
  if (own_capture) *own_capture = src.session.empty();
  if (src.session.empty()) {
    for (const auto& c : model.cameras)
      if (c.session_frame == frame) return ViewCamera{c.intrinsics, c.world_from_camera};
    return fail(fmt::format("session: frame {} is not one of the model's cameras (held out?); its camera comes from a session", frame));
  }
  auto cams = SessionCameras::load(src);
  if (!cams) return std::unexpected(cams.error());
  if (own_capture) *own_capture = model.session.empty() || model.session == cams->session.name;
  return cams->view(frame);
}

namespace {

ViewCamera scaled(ViewCamera v, double s) {
  if (s == 1) return v;
  Intrinsics& K = v.K;
  const int w = std::max(1, int(std::lround(K.width * s))), h = std::max(1, int(std::lround(K.height * s)));
  const double sx = double(w) / K.width, sy = double(h) / K.height;
  K.fx *= sx, K.fy *= sy;
  K.cx = (K.cx + 0.5) * sx - 0.5, K.cy = (K.cy + 0.5) * sy - 0.5;
  K.width = w, K.height = h;
  return v;
}

ImageU8 rgb_of(const ImageU8& rgba) {
  ImageU8 out(rgba.width, rgba.height, 3);
  for (size_t i = 0; i < rgba.pixels(); ++i)
    for (int c = 0; c < 3; ++c) out.data[i * 3 + c] = rgba.data[i * 4 + c];
  return out;
}

void add_selection(Report& rep, const DrawStats& st, const std::string& suffix) {
  rep.counts["facets_drawn" + suffix] = double(st.selection.drawn);
  rep.counts["frame_ms" + suffix] = st.frame_ms;
  if (st.fitted_on_cpu) rep.params["fitted_pass"] = std::string("cpu");
  if (st.backdrop_own_photo) rep.counts["backdrop_from_the_cameras_own_photo" + suffix] = 1;
  // The image-based billboards' selection, where it ran (the fitted pass
  // and a mesh alone select none: their frames list no such counters).
  const SelectionStats& se = st.selection;
  if (se.seconds > 0 || se.outside_frustum + se.back_facing + se.no_camera > 0) {
    rep.counts["selection_ms" + suffix] = se.seconds * 1e3;
    rep.skipped["facets_outside_frustum" + suffix] = double(se.outside_frustum);
    rep.skipped["facets_back_facing" + suffix] = double(se.back_facing);
    rep.skipped["facets_without_camera" + suffix] = double(se.no_camera);
    rep.skipped["blending_one_exact_camera" + suffix] = double(se.exact_camera);
  }
  if (st.selection.cameras_pruned) rep.skipped["blended_cameras_below_min_weight" + suffix] = double(st.selection.cameras_pruned);
  if (st.triangles) rep.counts["mesh_triangles" + suffix] = double(st.triangles);
  if (st.facets_on_mesh) rep.skipped["billboards_left_to_the_reliable_mesh" + suffix] = double(st.facets_on_mesh);
  if (st.lod.nodes_visited) {
    rep.counts["lod_node_billboards" + suffix] = double(st.lod.node_billboards);
    rep.counts["lod_facets_replaced" + suffix] = double(st.lod.facets_replaced);
    rep.counts["lod_nodes_visited" + suffix] = double(st.lod.nodes_visited);
    rep.counts["lod_refined_contour" + suffix] = double(st.lod.refined_contour);
    rep.counts["lod_refined_luminance" + suffix] = double(st.lod.refined_luminance);
    rep.counts["lod_refined_texel" + suffix] = double(st.lod.refined_texel);
    rep.counts["lod_ms" + suffix] = st.lod.seconds * 1e3;
    rep.counts["lod_loose_facets" + suffix] = double(st.lod.loose_facets);
    rep.skipped["facets_back_facing_by_normal_cone" + suffix] = double(st.lod.facets_back_cone);
    rep.skipped["facets_outside_frustum_by_node" + suffix] = double(st.lod.facets_outside_frustum);
    rep.skipped["facets_outside_visual_field" + suffix] = double(st.lod.facets_outside_field);
  }
}

struct Renderer {
  std::unique_ptr<GlContext> context;
  std::unique_ptr<ModelRenderer> renderer;  // holds the model (one copy in memory)
  const Model& model() const { return renderer->model(); }
  std::optional<ImageU8> backdrop;  // the model's backdrop plate, where it has one
};

// `splats`: a snapshot of the fit (splats_<S>s.bin) drawn instead of the model's.
Result<Renderer> open_model(const fs::path& dir, const fs::path& splats = {}) {
  Renderer r;
  // The octree is read when billboards first draw (a fitted view never does).
  auto model = load_model(dir, ModelLoad{.octree = false});
  if (!model) return std::unexpected(model.error());
  if (!splats.empty()) {
    if (model->splats.empty()) return fail(dir.string() + ": the model has no fit, so no layout for " + splats.string());
    auto sp = load_splat_payload(splats, model->splat_layout);
    if (!sp) return std::unexpected(sp.error());
    model->splats = std::move(*sp);
  }
  auto plate = load_backdrop(*model, dir);
  if (!plate) return std::unexpected(plate.error());
  r.backdrop = std::move(*plate);
  auto ctx = create_headless_context();
  if (!ctx) return std::unexpected(ctx.error());
  r.context = std::move(*ctx);
  auto mr = ModelRenderer::create(std::move(*model), dir);
  if (!mr) return std::unexpected(mr.error());
  r.renderer = std::move(*mr);
  return r;
}

}  // namespace

Status RenderJob::validate() const {
  if (!(scale > 0 && scale <= 8)) return fail(ErrorCode::invalid, "scale: must be in (0, 8]");
  if (!view && view_file.empty()) return fail(ErrorCode::invalid, "view: give a session frame or a view file");
  if (background)
    for (float c : *background)
      if (!(c >= 0 && c <= 1)) return fail(ErrorCode::invalid, "background: each channel must be in [0, 1]");
  return {};
}

Result<RenderSummary> run_render_job(const RenderJob& job) {
  Stopwatch clock;
  if (auto st = job.validate(); !st) return std::unexpected(st.error());
  // Each phase's seconds (counts.seconds_*), so the time to the first frame
  // shows apart from the image's size (the read back and the PNG).
  double mark = 0;
  const auto phase = [&](double* out) { const double now = clock.seconds(); *out = now - mark, mark = now; };
  double t_open = 0, t_view = 0, t_draw = 0, t_read = 0, t_write = 0;
  auto r = open_model(job.model);
  if (!r) return std::unexpected(r.error());
  phase(&t_open);
  bool own = false;
  Result<ViewCamera> view = !job.view_file.empty() ? load_view_file(job.view_file)
                            : job.view              ? frame_view(r->model(), job.source, *job.view, &own)
                                                    : Result<ViewCamera>(fail("no view (validate() refuses this)"));
  if (!view) return std::unexpected(view.error());
  const ViewCamera v = scaled(*view, job.scale);
  phase(&t_view);
  auto fb = Framebuffer::create(v.K.width, v.K.height);
  if (!fb) return std::unexpected(fb.error());
  RenderSummary sum;
  Report& rep = sum.report;
  rep.stage = "render";
  DrawOptions draw = job.draw;
  // The background asked for, else the model's own (the capture's), else black.
  if (const auto& bg = job.background ? job.background : r->model().background) std::copy(bg->begin(), bg->end(), draw.background);
  // A frame of the model's own capture, at the photos' size: on its backdrop plate.
  if (own && job.backdrop_plate && !job.background && !job.environment && r->backdrop && r->backdrop->width == v.K.width &&
      r->backdrop->height == v.K.height)
    draw.backdrop = &*r->backdrop;
  else if (r->backdrop)
    rep.skipped[!job.backdrop_plate || job.background ? "backdrop_plate_not_asked" : "backdrop_plate_not_this_view"] = 1;
  PreparedEnvironment env;
  if (job.environment) {
    auto e = prepare_environment(*job.environment, r->model().bounds);
    if (!e) return std::unexpected(e.error());
    env = std::move(*e);
    draw.environment = env.renderer.get();
    report_environment(env, rep);
  }
  auto st = r->renderer->draw(v, draw, *fb);
  if (!st) return std::unexpected(st.error());
  phase(&t_draw);
  const ImageU8 image = fb->read_rgb();
  phase(&t_read);
  if (auto w = write_image(job.out, image); !w) return std::unexpected(w.error());
  phase(&t_write);
  rep.counts["seconds_open_model"] = t_open;
  rep.counts["seconds_view"] = t_view;
  rep.counts["seconds_draw"] = t_draw;
  rep.counts["seconds_to_frame"] = t_open + t_view + t_draw;
  rep.counts["seconds_read_back"] = t_read;
  rep.counts["seconds_write_png"] = t_write;
  if (job.environment) rep.params["envmap_bound"] = st->envmap_bound;
  add_selection(rep, *st, "");
  rep.counts["triangles"] = double(st->triangles);
  rep.counts["texture_mib"] = double(r->renderer->texture_bytes()) / (1 << 20);
  rep.params["geometry"] = std::string(geometry_name(job.draw.geometry));
  rep.params["depth_clip"] = job.draw.depth_clip;
  rep.params["cameras"] = double(job.draw.selection.cameras);
  rep.params["width"] = double(v.K.width);
  rep.params["height"] = double(v.K.height);
  rep.params["renderer"] = r->context->describe();
  sum.draw = *st;
  sum.width = v.K.width, sum.height = v.K.height;
  sum.texture_mib = double(r->renderer->texture_bytes()) / (1 << 20);
  sum.renderer = r->context->describe();
  sum.seconds = rep.seconds = clock.seconds();
  return sum;
}

namespace {

// The silhouette band's half-width in pixels: a matte's fractional edge and
// the pixels beside it, where a drawing's hard edges or dark fringes show.
constexpr int kMatteBandPx = 2;

// A way of drawing the model that eval compares (billboards, and the baselines).
struct EvalMethod {
  std::string name;
  DrawOptions draw;
};

std::vector<EvalMethod> eval_methods(const EvalJob& job, const ModelRenderer& renderer) {
  std::vector<EvalMethod> methods;
  if (renderer.has_splats()) {
    EvalMethod fitted{"fitted", job.draw};
    fitted.draw.geometry = DrawOptions::Geometry::kSplats;
    methods.push_back(fitted);
  }
  // A model reconstructed without camera images draws only its fit.
  if (!renderer.has_textures()) return methods;
  methods.push_back({"billboards", job.draw});
  methods.back().draw.mesh_reliability = 0;
  if (job.draw.mesh_reliability > 0 && renderer.has_mesh()) methods.push_back({"hybrid", job.draw});
  if (job.baselines) {
    EvalMethod noclip{"no_clip", job.draw};
    noclip.draw.depth_clip = false;
    methods.push_back(noclip);
    for (auto [name, g] : {std::pair{"mesh", DrawOptions::Geometry::kMesh}, std::pair{"surface", DrawOptions::Geometry::kSurface}}) {
      if (!renderer.has_mesh(g)) continue;
      EvalMethod m{name, job.draw};
      m.draw.geometry = g;
      methods.push_back(m);
    }
  }
  if (!job.only.empty()) std::erase_if(methods, [&](const EvalMethod& m) { return !job.only.count(m.name); });
  return methods;
}

// A frame's photo on the evaluation's background, the object's pixels in it.
struct EvalPhoto {
  ImageU8 photo, object;
  // The frame's own fractional matte (a data set's alpha) and its
  // silhouette band (matte_band): what each drawing's coverage is checked
  // against. Empty without a matte.
  std::optional<ImageU8> matte, band;
  std::string mask_source = "whole_image";
  std::array<float, 3> background{0, 0, 0};
};

// The background: asked for, else the session's, else the backdrop's colour
// (object-centre sessions), else black. A photo with a matte composited on a
// session background is moved onto the asked one: photo + (b' - b)(1 - alpha).
Result<EvalPhoto> eval_photo(const Session& s, int frame, const Intrinsics& K, const std::optional<std::array<float, 3>>& asked) {
  const Frame& f = s.frames[size_t(frame)];
  auto photo = load_color(s, f);
  if (!photo) return std::unexpected(photo.error());
  if (photo->width != K.width || photo->height != K.height)
    return fail(fmt::format("frame {}: photo is {}x{}, its camera {}x{}", frame, photo->width, photo->height, K.width, K.height));
  EvalPhoto e;
  e.photo = std::move(*photo);
  e.object = ImageU8(e.photo.width, e.photo.height, 1, 255);
  std::optional<ImageU8> matte;
  if (!f.mask.empty()) {
    auto m = load_mask(s, f);
    if (!m) return std::unexpected(m.error());
    matte = std::move(*m);
  }
  if (asked) e.background = *asked;
  else if (s.background) e.background = *s.background;
  else if (s.layout == Layout::kObjectCentre) {
    const Backdrop b = border_backdrop(e.photo);
    for (size_t c = 0; c < 3 && c < b.color.size(); ++c) e.background[c] = float(b.color[c]) / 255.f;
  }
  if (matte && s.background && e.background != *s.background)
    for (size_t i = 0; i < e.photo.pixels(); ++i)
      for (size_t c = 0; c < 3; ++c) {
        const float shift = (e.background[c] - (*s.background)[c]) * 255.f * (255 - matte->data[i]) / 255.f;
        e.photo.data[i * 3 + c] = uint8_t(std::clamp(std::lround(e.photo.data[i * 3 + c] + shift), 0L, 255L));
      }
  const fs::path truth = s.root / "ground_truth" / "depth_color" / fmt::format("{:04d}.exr", frame);
  if (fs::exists(truth)) {
    auto d = read_image_float(truth);
    if (!d) return std::unexpected(d.error());
    for (size_t i = 0; i < e.object.pixels() && i < d->pixels(); ++i)
      e.object.data[i] = d->data[i * size_t(d->channels)] > 0 ? 255 : 0;
    e.mask_source = "ground_truth";
  } else if (matte) {
    for (size_t i = 0; i < e.object.pixels(); ++i) e.object.data[i] = matte->data[i] ? 255 : 0;
    e.mask_source = "matte";
  } else if (s.layout == Layout::kObjectCentre) {
    if (auto m = backdrop_mask(e.photo)) e.object = std::move(*m), e.mask_source = "backdrop";
  }
  if (matte) {
    auto band = matte_band(*matte, kMatteBandPx);
    if (!band) return std::unexpected(band.error());
    e.band = std::move(*band);
    e.matte = std::move(matte);
  }
  return e;
}

// Every method's figures over the frames, for the means.
struct EvalSeries {
  std::map<std::string, std::vector<double>> psnr, ssim, full_psnr, full_ssim, frame_ms, coverage, psnr_held, psnr_input,
      full_psnr_held, matte_mae, matte_edge_mae, edge_psnr;
};

// One frame drawn by every method and compared with its photo, over the
// whole image and over the object's pixels joined with every drawn pixel: a
// row of eval.csv, the strip PNG (photo | methods), the figures into `series`.
// With `mattes` (every evaluated frame has one) each drawing's coverage is
// checked against the frame's matte too.
Status eval_frame(const EvalJob& job, const Renderer& m, const ViewCamera& view, int frame, bool held, bool mattes,
                  std::vector<EvalMethod>& methods, const EvalPhoto& e, const ImageU8* plate, EvalSeries& series,
                  SweepTable& table, Report& rep) {
  if (mattes && !e.matte) return fail(fmt::format("frame {}: has no matte, the frames before it had", frame));
  std::vector<ImageU8> drawn;
  std::vector<DrawStats> stats;
  auto fb = Framebuffer::create(view.K.width, view.K.height);
  if (!fb) return std::unexpected(fb.error());
  for (auto& method : methods) {
    std::copy(e.background.begin(), e.background.end(), method.draw.background);
    method.draw.backdrop = plate;
    auto st = m.renderer->draw(view, method.draw, *fb);
    if (!st) return std::unexpected(st.error());
    drawn.push_back(fb->read_rgba());
    stats.push_back(*st);
  }
  ImageU8 mask = e.object;
  for (const auto& d : drawn)
    for (size_t i = 0; i < mask.pixels(); ++i)
      if (d.data[i * 4 + 3]) mask.data[i] = 255;
  size_t mask_px = 0, object_px = 0;
  for (size_t i = 0; i < mask.pixels(); ++i) mask_px += mask.data[i] != 0, object_px += e.object.data[i] != 0;
  std::vector<double> row{double(frame), held ? 1.0 : 0.0, double(mask_px)};
  ImageU8 strip(e.photo.width * int(1 + methods.size()), e.photo.height, 3);
  auto paste = [&](const ImageU8& img, int slot) {
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x)
        for (int c = 0; c < 3; ++c) strip.at(slot * img.width + x, y, c) = img.at(x, y, c);
  };
  paste(e.photo, 0);
  for (size_t k = 0; k < methods.size(); ++k) {
    const ImageU8 rgb = rgb_of(drawn[k]);
    paste(rgb, int(k) + 1);
    auto p = psnr(rgb, e.photo, &mask);
    auto q = ssim(rgb, e.photo, &mask);
    auto fp = psnr(rgb, e.photo);
    auto fq = ssim(rgb, e.photo);
    for (const auto* r : {&p, &q, &fp, &fq})
      if (!*r) return fail(fmt::format("frame {}: {}", frame, r->error().message));
    *p = finite_psnr(*p), *fp = finite_psnr(*fp);
    size_t covered = 0;
    for (size_t i = 0; i < e.object.pixels(); ++i) covered += e.object.data[i] && drawn[k].data[i * 4 + 3];
    const double cov = object_px ? double(covered) / double(object_px) : 0.0;
    const std::string& n = methods[k].name;
    series.psnr[n].push_back(*p), series.ssim[n].push_back(*q), series.frame_ms[n].push_back(stats[k].frame_ms);
    series.full_psnr[n].push_back(*fp), series.full_ssim[n].push_back(*fq);
    series.coverage[n].push_back(cov);
    (held ? series.psnr_held : series.psnr_input)[n].push_back(*p);
    if (held) series.full_psnr_held[n].push_back(*fp);
    rep.errors[fmt::format("psnr_db_{}_frame_{:04d}", n, frame)] = *p;
    rep.errors[fmt::format("full_psnr_db_{}_frame_{:04d}", n, frame)] = *fp;
    for (double x : {*p, *q, cov, stats[k].frame_ms, *fp, *fq}) row.push_back(x);
    if (mattes) {
      // The drawing's coverage against the frame's true matte; the colour
      // in its silhouette band (dark or light fringes).
      ImageU8 alpha(drawn[k].width, drawn[k].height, 1);
      for (size_t i = 0; i < alpha.pixels(); ++i) alpha.data[i] = drawn[k].data[i * 4 + 3];
      auto me = matte_error(alpha, *e.matte, *e.band);
      if (!me) return fail(fmt::format("frame {}: {}", frame, me.error().message));
      double edge = std::numeric_limits<double>::quiet_NaN();
      if (me->edge_pixels) {
        auto ep = psnr(rgb, e.photo, &*e.band);
        if (!ep) return fail(fmt::format("frame {}: {}", frame, ep.error().message));
        edge = finite_psnr(*ep);
        series.edge_psnr[n].push_back(edge);
        series.matte_edge_mae[n].push_back(me->edge_mae);
        rep.errors[fmt::format("matte_edge_mae_{}_frame_{:04d}", n, frame)] = me->edge_mae;
      }
      series.matte_mae[n].push_back(me->mae);
      for (double x : {me->mae, me->edge_mae, edge}) row.push_back(x);
    }
    if (k == 0) add_selection(rep, stats[k], fmt::format("_frame_{:04d}", frame));
  }
  table.rows.push_back(row);
  return write_image(job.out / fmt::format("frame_{:04d}.png", frame), strip);
}

double mean_of(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / double(v.size());
}

// The means over the frames per method, typed, and in the report with each
// baseline's difference.
void eval_summary(const EvalJob& job, const std::vector<EvalMethod>& methods, EvalSeries& series, EvalSummary& sum) {
  Report& rep = sum.report;
  for (const auto& m : methods) {
    const std::string& n = m.name;
    EvalMethodFigures f;
    f.name = n;
    f.psnr_db = mean_of(series.psnr[n]), f.ssim = mean_of(series.ssim[n]);
    f.full_psnr_db = mean_of(series.full_psnr[n]), f.full_ssim = mean_of(series.full_ssim[n]);
    f.coverage = mean_of(series.coverage[n]), f.frame_ms = mean_of(series.frame_ms[n]);
    if (!series.psnr_held[n].empty()) f.psnr_db_held_out = mean_of(series.psnr_held[n]);
    if (!series.full_psnr_held[n].empty()) f.full_psnr_db_held_out = mean_of(series.full_psnr_held[n]);
    if (!series.psnr_input[n].empty()) f.psnr_db_input_views = mean_of(series.psnr_input[n]);
    if (!series.matte_mae[n].empty()) f.matte_mae = mean_of(series.matte_mae[n]);
    if (!series.matte_edge_mae[n].empty()) {
      f.matte_edge_mae = mean_of(series.matte_edge_mae[n]);
      f.edge_psnr_db = mean_of(series.edge_psnr[n]);
    }
    rep.errors["psnr_db_" + n] = f.psnr_db;
    rep.errors["ssim_" + n] = f.ssim;
    rep.errors["full_psnr_db_" + n] = f.full_psnr_db;
    rep.errors["full_ssim_" + n] = f.full_ssim;
    rep.counts["coverage_" + n] = f.coverage;
    rep.counts["frame_ms_" + n] = f.frame_ms;
    if (f.psnr_db_held_out) rep.errors["psnr_db_" + n + "_held_out"] = *f.psnr_db_held_out;
    if (f.full_psnr_db_held_out) rep.errors["full_psnr_db_" + n + "_held_out"] = *f.full_psnr_db_held_out;
    if (f.psnr_db_input_views) rep.errors["psnr_db_" + n + "_input_views"] = *f.psnr_db_input_views;
    if (f.matte_mae) rep.errors["matte_mae_" + n] = *f.matte_mae;
    if (f.matte_edge_mae) rep.errors["matte_edge_mae_" + n] = *f.matte_edge_mae;
    if (f.edge_psnr_db) rep.errors["edge_psnr_db_" + n] = *f.edge_psnr_db;
    sum.methods.push_back(std::move(f));
  }
  if (auto g = sum.gain_db("hybrid", "billboards")) {
    rep.errors["hybrid_over_billboards_db"] = *g;
    rep.params["mesh_reliability"] = job.draw.mesh_reliability;
  }
  if (auto g = sum.gain_db("billboards", "no_clip")) rep.errors["depth_clip_gain_db"] = *g;
  for (const std::string n : {"billboards", "mesh"})
    if (auto g = sum.gain_db("fitted", n)) rep.errors["fitted_over_" + n + "_db"] = *g;
  for (const std::string n : {"mesh", "surface"}) {
    if (auto g = sum.gain_db("billboards", n)) rep.errors["billboards_over_" + n + "_db"] = *g;
    if (auto g = sum.gain_db("billboards", n, true)) rep.errors["billboards_over_" + n + "_held_out_db"] = *g;
  }
}

}  // namespace

const EvalMethodFigures* EvalSummary::method(std::string_view name) const {
  for (const auto& m : methods)
    if (m.name == name) return &m;
  return nullptr;
}

std::optional<double> EvalSummary::gain_db(std::string_view a, std::string_view b, bool held_out) const {
  const EvalMethodFigures *x = method(a), *y = method(b);
  if (!x || !y) return std::nullopt;
  if (!held_out) return x->psnr_db - y->psnr_db;
  if (!x->psnr_db_held_out || !y->psnr_db_held_out) return std::nullopt;
  return *x->psnr_db_held_out - *y->psnr_db_held_out;
}

Status EvalJob::validate() const {
  if (frames.empty()) return fail(ErrorCode::invalid, "frames: give the frames to evaluate");
  if (source.session.empty()) return fail(ErrorCode::invalid, "session: is needed, the photos come from it");
  for (const auto& m : only)
    if (m != "fitted" && m != "billboards" && m != "hybrid" && m != "no_clip" && m != "mesh" && m != "surface")
      return fail(ErrorCode::invalid, "only: '" + m + "' is not a method (fitted, billboards, hybrid, no_clip, mesh, surface)");
  if (background)
    for (float c : *background)
      if (!(c >= 0 && c <= 1)) return fail(ErrorCode::invalid, "background: each channel must be in [0, 1]");
  return {};
}

// Open the model and the session's cameras; per frame, the photo and every
// method's drawing compared with it; the means; eval.csv.
Result<EvalSummary> run_eval_job(const EvalJob& job) {
  Stopwatch clock;
  if (auto st = job.validate(); !st) return std::unexpected(st.error());
  auto r = open_model(job.model, job.splats);
  if (!r) return std::unexpected(r.error());
  auto cameras = SessionCameras::load(job.source);
  if (!cameras) return std::unexpected(cameras.error());
  const Session& s = cameras->session;
  // The model's own frames: those of its cameras, when the session is the
  // one it was made from (another session's frame i is a different view).
  std::set<int> in_model;
  const bool own_capture = r->model().session.empty() || r->model().session == s.name;
  if (own_capture)
    for (const auto& c : r->model().cameras) in_model.insert(c.session_frame);
  std::error_code ec;
  fs::create_directories(job.out, ec);
  if (ec) return fail("cannot create " + job.out.string() + ": " + ec.message());

  std::vector<EvalMethod> methods = eval_methods(job, *r->renderer);
  if (methods.empty()) return fail(ErrorCode::invalid, "only: none of the methods asked for can be drawn with this model");
  EvalSummary sum;
  Report& rep = sum.report;
  rep.stage = "eval";
  if (!r->renderer->has_textures()) rep.skipped["methods_without_camera_images"] = 1;
  SweepTable table;
  table.columns = {"frame", "held_out", "mask_pixels"};
  // Every frame with a matte (a data set's alpha): the coverage checked too.
  const bool mattes = std::all_of(job.frames.begin(), job.frames.end(), [&](int f) {
    return f >= 0 && size_t(f) < s.frames.size() && !s.frames[size_t(f)].mask.empty();
  });
  for (const auto& m : methods) {
    for (const char* q : {"psnr_db_", "ssim_", "coverage_", "frame_ms_", "full_psnr_db_", "full_ssim_"})
      table.columns.push_back(q + m.name);
    if (mattes)
      for (const char* q : {"matte_mae_", "matte_edge_mae_", "edge_psnr_db_"}) table.columns.push_back(q + m.name);
  }
  EvalSeries series;
  Progress progress("eval", job.frames.size());
  for (int frame : job.frames) {
    auto view = cameras->view(frame);
    if (!view) return std::unexpected(view.error());
    auto photo = eval_photo(s, frame, view->K, job.background);
    if (!photo) return std::unexpected(photo.error());
    sum.mask_source = photo->mask_source;
    sum.background = photo->background;
    const bool held = !in_model.count(frame);
    // Frames of the model's own capture: on its backdrop plate (the fixed
    // camera's view behind the object), where it has one.
    const ImageU8* plate = nullptr;
    if (own_capture && job.backdrop_plate && !job.background && r->backdrop && r->backdrop->width == view->K.width &&
        r->backdrop->height == view->K.height)
      plate = &*r->backdrop, ++sum.frames_on_backdrop_plate;
    if (auto st = eval_frame(job, *r, *view, frame, held, mattes, methods, *photo, plate, series, table, rep); !st)
      return std::unexpected(st.error());
    progress.tick();
  }
  progress.done();
  eval_summary(job, methods, series, sum);
  if (!job.only.empty()) rep.skipped["methods_not_asked"] = double(eval_methods(EvalJob{.draw = job.draw, .baselines = job.baselines}, *r->renderer).size() - methods.size());
  if (!job.baselines) rep.skipped["baselines_not_asked"] = 1;
  else {
    if (!r->renderer->has_mesh(DrawOptions::Geometry::kMesh)) rep.skipped["mesh_baseline_no_patch_mesh"] = 1;
    if (!r->renderer->has_mesh(DrawOptions::Geometry::kSurface)) rep.skipped["surface_baseline_no_surface_mesh"] = 1;
  }
  sum.views = job.frames.size();
  sum.held_out_views = size_t(std::count_if(job.frames.begin(), job.frames.end(), [&](int f) { return !in_model.count(f); }));
  sum.facets = r->model().facets.size();
  rep.counts["views"] = double(sum.views);
  rep.counts["held_out_views"] = double(sum.held_out_views);
  if (r->backdrop) rep.counts["frames_on_backdrop_plate"] = double(sum.frames_on_backdrop_plate);
  if (r->backdrop && (!job.backdrop_plate || job.background)) rep.skipped["backdrop_plate_not_asked"] = 1;
  rep.counts["facets"] = double(sum.facets);
  rep.params["mask"] = sum.mask_source;
  if (!mattes) rep.skipped["matte_check_frames_without_matte"] = 1;
  else rep.params["matte_band_px"] = double(kMatteBandPx);
  rep.params["background"] = fmt::format("{:.3g},{:.3g},{:.3g}", sum.background[0], sum.background[1], sum.background[2]);
  rep.params["cameras"] = double(job.draw.selection.cameras);
  rep.params["renderer"] = r->context->describe();
  if (auto w = table.write_csv(job.out / "eval.csv"); !w) return std::unexpected(w.error());
  sum.seconds = rep.seconds = clock.seconds();
  return sum;
}

Result<std::vector<FrameTiming>> time_orbit(const fs::path& model_dir, const std::vector<DrawOptions>& draws, int width,
                                            int height, int frames) {
  if (frames < 1) return fail("time_orbit: at least one frame");
  auto r = open_model(model_dir);
  if (!r) return std::unexpected(r.error());
  auto fb = Framebuffer::create(width, height);
  if (!fb) return std::unexpected(fb.error());
  // One frame each unmeasured: shader compilation and texture residency.
  for (const auto& d : draws)
    if (auto st = r->renderer->draw(default_orbit_view(r->model(), width, height), d, *fb); !st) return std::unexpected(st.error());
  std::vector<FrameTiming> out(draws.size());
  std::vector<double> drawn(draws.size(), 0);
  for (int i = 0; i < frames; ++i) {
    const ViewCamera v = default_orbit_view(r->model(), width, height, 2 * std::numbers::pi * i / frames);
    for (size_t k = 0; k < draws.size(); ++k) {
      auto st = r->renderer->draw(v, draws[k], *fb);
      if (!st) return std::unexpected(st.error());
      out[k].frame_ms.push_back(st->frame_ms);
      drawn[k] += double(st->selection.drawn);
    }
  }
  for (size_t k = 0; k < draws.size(); ++k) {
    FrameTiming& t = out[k];
    double sum = 0;
    for (double x : t.frame_ms) sum += x;
    t.mean_ms = sum / frames;
    t.median_ms = median(t.frame_ms);
    t.facets_drawn_mean = drawn[k] / frames;
    t.renderer = r->context->describe();
  }
  return out;
}

Result<FrameTiming> time_orbit(const fs::path& model_dir, const DrawOptions& draw, int width, int height, int frames) {
  auto t = time_orbit(model_dir, std::vector<DrawOptions>{draw}, width, height, frames);
  if (!t) return std::unexpected(t.error());
  return std::move(t->front());
}

}  // namespace s2r
