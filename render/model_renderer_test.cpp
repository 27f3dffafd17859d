// The billboard renderer on a model whose truth is known exactly: a textured
// square in the plane z = 0 seen by five cameras on an arc (with a lens
// distortion), its camera textures computed analytically. Also: blending
// weights, the stiff cases of rendering, and the window
// drawing the same pixels as the headless context.
#include <gtest/gtest.h>
#include <spdlog/fmt/fmt.h>

#include <cmath>
#include <filesystem>
#include <numbers>

#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/image_metrics.h"
#include "core/mesh.h"
#include "render/facet_selection.h"
#include "render/gl_context.h"
#include "render/model_eval.h"
#include "render/model_renderer.h"
#include "render/test_xserver.h"
#include "render/viewer.h"
#include "reconstruct/splat_fit.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

constexpr double kHalf = 0.08;   // the square: |x|, |y| <= kHalf, z = 0
constexpr double kVoxel = 0.004;
constexpr double kDistance = 0.5;
const std::array<uint8_t, 3> kBackground{40, 40, 40};

std::array<uint8_t, 3> albedo(double x, double y) {
  auto c = [](double v) { return uint8_t(std::lround(127.5 + 100 * v)); };
  return {c(std::sin(60 * x) * std::cos(45 * y)), c(std::cos(80 * y)), c(std::sin(35 * (x + y)))};
}

Intrinsics lens() {
  Intrinsics K;
  K.width = 160, K.height = 120, K.fx = K.fy = 220, K.cx = 79.5, K.cy = 59.5;
  K.dist = {-0.08, 0.02, 0, 0, 0};
  return K;
}

// A camera on the arc in the x-z plane, looking at the origin, y down.
ViewCamera arc_camera(double angle_deg, double distance = kDistance) {
  const double a = angle_deg * std::numbers::pi / 180;
  const Eigen::Vector3d eye(distance * std::sin(a), 0, distance * std::cos(a));
  const Eigen::Vector3d z = -eye.normalized();
  const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
  ViewCamera v;
  v.K = lens();
  v.world_from_camera.linear() << x, z.cross(x), z;
  v.world_from_camera.translation() = eye;
  return v;
}

// What a camera sees: colour and distance along each pixel's ray.
RgbazImage photograph(const ViewCamera& v) {
  RgbazImage img{ImageU8(v.K.width, v.K.height, 4), ImageF(v.K.width, v.K.height, 1)};
  for (int y = 0; y < v.K.height; ++y)
    for (int x = 0; x < v.K.width; ++x) {
      std::array<uint8_t, 3> c = kBackground;
      float dist = 0, alpha = 0;
      if (auto r = v.K.ray({double(x), double(y)})) {
        const Eigen::Vector3d d = v.world_from_camera.linear() * r->normalized();
        const Eigen::Vector3d o = v.world_from_camera.translation();
        if (std::abs(d.z()) > 1e-9) {
          const double t = -o.z() / d.z();
          const Eigen::Vector3d p = o + t * d;
          if (t > 0 && std::abs(p.x()) <= kHalf && std::abs(p.y()) <= kHalf)
            c = albedo(p.x(), p.y()), dist = float(t), alpha = 255;
        }
      }
      for (int k = 0; k < 3; ++k) img.rgba.at(x, y, k) = c[size_t(k)];
      img.rgba.at(x, y, 3) = uint8_t(alpha);
      img.distance.at(x, y) = dist;
    }
  return img;
}

ImageU8 rgb(const ImageU8& rgba) {
  ImageU8 out(rgba.width, rgba.height, 3);
  for (size_t i = 0; i < rgba.pixels(); ++i)
    for (int c = 0; c < 3; ++c) out.data[i * 3 + c] = rgba.data[i * 4 + size_t(c)];
  return out;
}

// The square's pixels in a view (alpha of its photograph).
ImageU8 square_mask(const ViewCamera& v) {
  const RgbazImage p = photograph(v);
  ImageU8 m(v.K.width, v.K.height, 1);
  for (size_t i = 0; i < m.pixels(); ++i) m.data[i] = p.rgba.data[i * 4 + 3];
  return m;
}

struct TestModel {
  fs::path dir;
  Model model;
};

// Facets on the square; `floaters` adds a spurious layer 3 w in front of it
// (what noisy depth leaves in free space).
TestModel make_model(const std::string& name, const std::vector<double>& camera_deg, bool floaters = false) {
  TestModel t;
  t.dir = fs::path(testing::TempDir()) / ("s2r_render_" + name);
  fs::remove_all(t.dir);
  fs::create_directories(t.dir / "cameras");
  Model& m = t.model;
  m.voxel_size_m = kVoxel;
  m.bounds = Eigen::AlignedBox3d(Eigen::Vector3d(-kHalf, -kHalf, -4 * kVoxel), Eigen::Vector3d(kHalf, kHalf, 4 * kVoxel));
  for (size_t i = 0; i < camera_deg.size(); ++i) {
    const ViewCamera v = arc_camera(camera_deg[i]);
    ModelCamera c{v.K, v.world_from_camera, fmt::format("cameras/{:04d}.exr", i), int(i)};
    EXPECT_TRUE(write_rgbaz(t.dir / c.texture, photograph(v)));
    m.cameras.push_back(c);
    m.facet_cameras.push_back(uint32_t(i));
  }
  const int n = int(std::floor(kHalf / kVoxel));
  for (double z : floaters ? std::vector<double>{0.0, 3 * kVoxel} : std::vector<double>{0.0})
    for (int i = -n; i <= n; ++i)
      for (int j = -n; j <= n; ++j) {
        FacetRecord f{};
        f.center[0] = float(i * kVoxel), f.center[1] = float(j * kVoxel), f.center[2] = float(z);
        f.size = float(kVoxel);
        f.normal[2] = 1;
        f.reliability = 1;
        f.first_camera = 0;
        f.camera_count = uint32_t(camera_deg.size());
        m.facets.push_back(f);
      }
  EXPECT_TRUE(save_model(t.dir, m));
  return t;
}

struct Gl {
  std::unique_ptr<GlContext> context;
  std::unique_ptr<ModelRenderer> renderer;
};

Gl open(const TestModel& t) {
  Gl g;
  auto ctx = create_headless_context();
  EXPECT_TRUE(ctx) << ctx.error().message;
  if (!ctx) return g;
  g.context = std::move(*ctx);
  auto r = ModelRenderer::create(t.model, t.dir);
  EXPECT_TRUE(r) << r.error().message;
  if (r) g.renderer = std::move(*r);
  return g;
}

ImageU8 draw(Gl& g, const ViewCamera& v, const DrawOptions& o, DrawStats* stats = nullptr) {
  auto fb = Framebuffer::create(v.K.width, v.K.height);
  EXPECT_TRUE(fb);
  auto st = g.renderer->draw(v, o, *fb);
  EXPECT_TRUE(st) << st.error().message;
  if (st && stats) *stats = *st;
  return fb->read_rgba();
}

double masked_psnr(const ImageU8& drawn_rgba, const ViewCamera& v) {
  const ImageU8 photo = rgb(photograph(v).rgba);
  ImageU8 mask = square_mask(v);
  for (size_t i = 0; i < mask.pixels(); ++i)
    if (drawn_rgba.data[i * 4 + 3]) mask.data[i] = 255;  // drawing off the square is an error too
  return *psnr(rgb(drawn_rgba), photo, &mask);
}

// Inside the square, `margin` pixels from its edge: where a point-sampled
// photo has no edge aliasing.
double interior_psnr(const ImageU8& drawn_rgba, const ViewCamera& v, int margin = 2) {
  const ImageU8 photo = rgb(photograph(v).rgba);
  const ImageU8 square = square_mask(v);
  ImageU8 mask(square.width, square.height, 1, 0);
  for (int y = margin; y < square.height - margin; ++y)
    for (int x = margin; x < square.width - margin; ++x) {
      bool all = true;
      for (int dy = -margin; dy <= margin && all; ++dy)
        for (int dx = -margin; dx <= margin && all; ++dx) all = square.at(x + dx, y + dy) != 0;
      mask.at(x, y) = all ? 255 : 0;
    }
  return *psnr(rgb(drawn_rgba), photo, &mask);
}

DrawOptions background_options() {
  DrawOptions o;
  for (int k = 0; k < 3; ++k) o.background[k] = kBackground[size_t(k)] / 255.f;
  return o;
}

const std::vector<double> kArc{-30, -15, 0, 15, 30};

TEST(Blending, WeightsSumToOneAndHandOverSmoothly) {
  float w[kMaxBlendCameras];
  const double exact[] = {0.0, 0.2, 0.3};
  ASSERT_EQ(blend_weights(exact, 3, 2, w), 1);
  EXPECT_EQ(w[0], 1.f);
  // Two cameras trade places in the ranking: the weight of the one leaving
  // the best k falls to zero before it leaves (no pop).
  const int k = 2;
  double last_w2 = -1;
  for (double b = 0.10; b <= 0.30; b += 0.001) {
    // a: 0.05 fixed; camera "2" at b; camera "3" at 0.2 fixed.
    std::vector<std::pair<double, int>> cams{{0.05, 1}, {b, 2}, {0.2, 3}};
    std::sort(cams.begin(), cams.end());
    double angles[3] = {cams[0].first, cams[1].first, cams[2].first};
    const int used = blend_weights(angles, 3, k, w);
    ASSERT_EQ(used, 2);
    EXPECT_NEAR(w[0] + w[1], 1.f, 1e-6);
    double w2 = 0;
    for (int j = 0; j < used; ++j) {
      if (cams[size_t(j)].second == 2) w2 = w[j];
    }
    if (last_w2 >= 0) {
      EXPECT_LT(std::abs(w2 - last_w2), 0.03) << "b = " << b;
    }
    last_w2 = w2;
  }
  EXPECT_EQ(last_w2, 0.0);  // camera 2 is out of the best two
  // Fewer cameras than k: every one used, finite.
  const double one[] = {0.4};
  ASSERT_EQ(blend_weights(one, 1, 3, w), 1);
  EXPECT_EQ(w[0], 1.f);
  EXPECT_EQ(blend_weights(one, 0, 3, w), 0);
}

TEST(Selection, CullsWhatTheViewCannotUseAndCountsIt) {
  const TestModel t = make_model("select", kArc);
  std::vector<FacetInstance> out;
  // From the front everything faces the eye and lies in the image.
  SelectionStats front = select_facets(t.model, arc_camera(0), {}, out);
  EXPECT_EQ(front.drawn, t.model.facets.size());
  EXPECT_EQ(front.exact_camera, t.model.facets.size());  // camera 2 is the view
  // From behind (a 180-degree turn): every facet faces away.
  SelectionStats back = select_facets(t.model, arc_camera(180), {}, out);
  EXPECT_EQ(back.back_facing, t.model.facets.size());
  EXPECT_EQ(back.drawn, 0u);
  // Looking away from the square: all outside the frustum.
  ViewCamera away = arc_camera(0);
  away.world_from_camera.linear() = away.world_from_camera.linear() * Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitY());
  SelectionStats none = select_facets(t.model, away, {}, out);
  EXPECT_EQ(none.outside_frustum, t.model.facets.size());
  // Weights of every drawn facet are finite and sum to 1, from any side.
  for (double deg : {0.0, 7.5, 44.0, 89.9, 135.0}) {
    SelectionOptions o;
    o.backface_cull = false;
    select_facets(t.model, arc_camera(deg), o, out);
    for (const auto& f : out) {
      float sum = 0;
      for (int j = 0; j < kMaxBlendCameras; ++j) {
        ASSERT_TRUE(std::isfinite(f.weight[j]));
        sum += f.weight[j];
      }
      ASSERT_NEAR(sum, 1.f, 1e-5) << deg;
    }
  }
}

TEST(Billboards, InputViewsReproduceTheirPhotos) {
  const TestModel t = make_model("input", kArc);
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  for (double deg : kArc) {
    const ViewCamera v = arc_camera(deg);
    DrawStats st;
    const ImageU8 img = draw(g, v, background_options(), &st);
    const double p = masked_psnr(img, v);
    RecordProperty(fmt::format("psnr_input_{}", int(deg)), fmt::format("{:.2f}", p));
    EXPECT_GE(p, 40.0) << "camera at " << deg << " deg";
    EXPECT_GT(st.selection.drawn, 0u);
  }
}

TEST(Billboards, HeldOutViewsAndDepthClippingAgainstFloaters) {
  // Cameras every 15 deg but the one at 0; the square has a layer of
  // spurious facets 3 w in front of it.
  const TestModel t = make_model("floaters", {-30, -15, 15, 30}, true);
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  for (double deg : {0.0, 7.5}) {
    const ViewCamera v = arc_camera(deg);
    DrawOptions on = background_options();
    on.selection.min_weight = 0;  // every camera of the best k: the clip alone is under test
    DrawOptions off = on;
    off.depth_clip = false;
    const ImageU8 img_on = draw(g, v, on), img_off = draw(g, v, off);
    const double p_on = interior_psnr(img_on, v);
    const double p_off = interior_psnr(img_off, v);
    const double p_edges = masked_psnr(img_on, v);
    if (std::getenv("S2R_TEST_IMAGES")) {
      write_image(t.dir / fmt::format("on_{}.png", deg), rgb(img_on));
      write_image(t.dir / fmt::format("off_{}.png", deg), rgb(img_off));
      write_image(t.dir / fmt::format("photo_{}.png", deg), rgb(photograph(v).rgba));
    }
    RecordProperty(fmt::format("psnr_held_out_{}_clip", deg), fmt::format("{:.2f}", p_on));
    RecordProperty(fmt::format("psnr_held_out_{}_no_clip", deg), fmt::format("{:.2f}", p_off));
    RecordProperty(fmt::format("psnr_held_out_{}_with_edges", deg), fmt::format("{:.2f}", p_edges));
    EXPECT_GE(p_on, 38.0) << deg;
    EXPECT_GT(p_on, p_off + 5.0) << "depth clipping should remove the floaters' misplaced texels at " << deg;
    // The square's edge in a point-sampled photo: one-pixel aliasing only.
    EXPECT_GE(p_edges, 22.0) << deg;
  }
}

TEST(Billboards, StiffViewsGiveBoundedImages) {
  const TestModel t = make_model("stiff", kArc);
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  // Grazing: the eye nearly in the square's plane.
  {
    const ViewCamera v = arc_camera(89.9);
    DrawStats st;
    draw(g, v, background_options(), &st);
    EXPECT_GE(st.frame_ms, 0.0);
  }
  // The eye inside the volume, among the facets.
  {
    ViewCamera v = arc_camera(0, 0.002);
    DrawStats st;
    draw(g, v, background_options(), &st);
    EXPECT_TRUE(std::isfinite(st.frame_ms));
  }
  // A 180-degree change between two frames: both draw.
  {
    DrawOptions o = background_options();
    o.selection.backface_cull = false;
    DrawStats a, b;
    draw(g, arc_camera(10), o, &a);
    draw(g, arc_camera(190), o, &b);
    EXPECT_GT(a.selection.drawn, 0u);
    EXPECT_GT(b.selection.drawn, 0u);
  }
  // The wrong image size is a clear error, not a crash.
  {
    auto fb = Framebuffer::create(32, 32);
    ASSERT_TRUE(fb);
    auto st = g.renderer->draw(arc_camera(0), background_options(), *fb);
    ASSERT_FALSE(st);
    EXPECT_NE(st.error().message.find("160x120"), std::string::npos) << st.error().message;
  }
}

TEST(Billboards, OneCameraZeroFacetsAndFacetsNoCameraSees) {
  // One input camera: its own view is exact, a nearby one is drawn.
  {
    const TestModel t = make_model("one", {0});
    Gl g = open(t);
    ASSERT_TRUE(g.renderer);
    EXPECT_GE(masked_psnr(draw(g, arc_camera(0), background_options()), arc_camera(0)), 40.0);
    EXPECT_GE(masked_psnr(draw(g, arc_camera(5), background_options()), arc_camera(5)), 20.0);
  }
  // Zero facets: an empty image, no error.
  {
    TestModel t = make_model("zero", kArc);
    t.model.facets.clear();
    ASSERT_TRUE(save_model(t.dir, t.model));
    Gl g = open(t);
    ASSERT_TRUE(g.renderer);
    DrawStats st;
    const ImageU8 img = draw(g, arc_camera(0), background_options(), &st);
    EXPECT_EQ(st.selection.drawn, 0u);
    for (size_t i = 0; i < img.pixels(); ++i) ASSERT_EQ(img.data[i * 4 + 3], 0);
  }
  // Facets no camera sees are counted and left out.
  {
    TestModel t = make_model("unseen", kArc);
    for (size_t i = 0; i < t.model.facets.size(); i += 2) t.model.facets[i].camera_count = 0;
    std::vector<FacetInstance> out;
    const SelectionStats st = select_facets(t.model, arc_camera(0), {}, out);
    EXPECT_EQ(st.no_camera, (t.model.facets.size() + 1) / 2);
    EXPECT_EQ(st.drawn + st.no_camera, t.model.facets.size());
  }
}

// The square as a patch mesh (a grid of w-sized cells, two triangles each),
// its left half (x < 0) reliable geometry, the right half fuzzy evidence.
TestModel make_hybrid_model() {
  TestModel t = make_model("hybrid", kArc);
  for (auto& f : t.model.facets) f.reliability = f.center[0] < 0 ? 0.9f : 0.2f;
  const int n = int(std::floor(kHalf / kVoxel));
  Mesh mesh;
  for (int j = -n; j <= n; ++j)
    for (int i = -n; i <= n; ++i) mesh.vertices.emplace_back(float(i * kVoxel), float(j * kVoxel), 0.f);
  const int side = 2 * n + 1;
  for (int j = 0; j + 1 < side; ++j)
    for (int i = 0; i + 1 < side; ++i) {
      const int a = j * side + i;
      mesh.faces.emplace_back(a, a + 1, a + side + 1);
      mesh.faces.emplace_back(a, a + side + 1, a + side);
    }
  EXPECT_TRUE(write_ply_mesh(t.dir / "patch_mesh.ply", mesh));
  t.model.patch_mesh = "patch_mesh.ply";
  EXPECT_TRUE(save_model(t.dir, t.model));
  return t;
}

TEST(Hybrid, PatchMeshWhereReliableBillboardsElsewhere) {
  const TestModel t = make_hybrid_model();
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  ASSERT_TRUE(g.renderer->has_mesh());
  const size_t total_triangles = 2 * size_t(std::pow(2 * std::floor(kHalf / kVoxel), 2));
  for (double deg : {0.0, 7.5}) {
    const ViewCamera v = arc_camera(deg);
    DrawOptions bb = background_options();
    DrawStats st_bb, st_h, st_all, st_none;
    const ImageU8 img_bb = draw(g, v, bb, &st_bb);
    // Threshold 0.5: the left half from the mesh (its triangles and a cell's
    // overlap into the right), the right half's billboards as before.
    DrawOptions hybrid = bb;
    hybrid.mesh_reliability = 0.5;
    const ImageU8 img_h = draw(g, v, hybrid, &st_h);
    EXPECT_GT(st_h.triangles, total_triangles / 2) << deg;
    EXPECT_LT(st_h.triangles, total_triangles * 6 / 10) << deg;
    size_t left = 0;
    for (const auto& f : t.model.facets) left += f.center[0] < 0;
    EXPECT_EQ(st_h.facets_on_mesh, left) << deg;
    EXPECT_EQ(st_h.selection.drawn + st_h.facets_on_mesh, st_bb.selection.drawn) << deg;
    const double p_bb = masked_psnr(img_bb, v), p_h = masked_psnr(img_h, v);
    RecordProperty(fmt::format("psnr_{}_billboards", deg), fmt::format("{:.2f}", p_bb));
    RecordProperty(fmt::format("psnr_{}_hybrid", deg), fmt::format("{:.2f}", p_h));
    RecordProperty(fmt::format("triangles_{}_hybrid", deg), std::to_string(st_h.triangles));
    // A flat square's mesh is its exact geometry: no worse than billboards, no gap at the seam.
    EXPECT_GE(p_h, std::min(p_bb, 38.0) - 0.5) << deg;
    // Above every facet's reliability: billboards everywhere, the same pixels.
    DrawOptions none = bb;
    none.mesh_reliability = 0.95;
    EXPECT_EQ(draw(g, v, none, &st_none).data, img_bb.data) << deg;
    EXPECT_EQ(st_none.triangles, 0u);
    // Below every facet's: the mesh everywhere, no billboard left.
    DrawOptions all = bb;
    all.mesh_reliability = 0.1;
    draw(g, v, all, &st_all);
    EXPECT_EQ(st_all.triangles, total_triangles) << deg;
    EXPECT_EQ(st_all.selection.drawn, 0u) << deg;
  }
}

// Fitted billboards on the square, coloured by its albedo, with a
// view-dependent term: the GL pass against the fit's own CPU image formation.
std::vector<Splat> square_splats(float sigma_voxels = 0.6f) {
  std::vector<Splat> out;
  const int n = int(std::floor(kHalf / kVoxel));
  for (int i = -n; i <= n; ++i)
    for (int j = -n; j <= n; ++j) {
      Splat s;
      s.anchor = Eigen::Vector3f(float(i * kVoxel), float(j * kVoxel), 0.f);
      s.voxel = float(kVoxel);
      s.log_sigma = std::log(sigma_voxels * float(kVoxel));
      s.opacity_logit = 1.5f;
      const auto a = albedo(i * kVoxel, j * kVoxel);
      for (int c = 0; c < 3; ++c) s.sh[size_t(c)] = (a[size_t(c)] / 255.f - 0.5f) / 0.28209479177387814f;
      s.sh[3 * 3 + 0] = 0.3f;  // red brightens towards -x
      out.push_back(s);
    }
  return out;
}

void put_splats(Model& m, const std::vector<Splat>& splats) {
  m.splat_layout.sh_degree = 1;
  m.splats.clear();
  for (const Splat& s : splats) {
    m.splats.insert(m.splats.end(), {s.anchor.x(), s.anchor.y(), s.anchor.z(), s.sigma(), s.opacity()});
    for (int k = 0; k < 12; ++k) m.splats.push_back(s.sh[size_t(k)]);
  }
}

// Footprints of a few pixels and under a pixel, with the model's pixel
// filter and without (a model fitted before it): both passes draw the fit's
// image formation with the model's own filter.
TEST(Fitted, GlDrawsTheFitsImageFormation) {
  // (under a pixel, filters 0.3 and 0 px^2: far enough apart that drawing
  // with the other shows, whatever the default)
  for (auto [sigma_voxels, filter] : {std::pair{0.6f, kSplatPixelFilterPx2}, std::pair{0.08f, 0.3f},
                                      std::pair{0.08f, 0.f}}) {
  SCOPED_TRACE(sigma_voxels);
  SCOPED_TRACE(filter);
  TestModel t = make_model("fitted", kArc);
  const auto splats = square_splats(sigma_voxels);
  put_splats(t.model, splats);
  t.model.splat_layout.pixel_filter_px2 = filter;
  ASSERT_TRUE(save_model(t.dir, t.model));
  auto loaded = load_model(t.dir);
  ASSERT_TRUE(loaded) << loaded.error().message;
  ASSERT_EQ(loaded->splat_count(), splats.size());
  EXPECT_FLOAT_EQ(loaded->splat_layout.pixel_filter_px2, filter);
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  DrawOptions o = background_options();
  o.geometry = DrawOptions::Geometry::kSplats;
  // Both passes: the GL one and the CPU compositor laid over the target.
  for (auto pass : {DrawOptions::FittedPass::kGl, DrawOptions::FittedPass::kCpu})
  for (double deg : {-40.0, 7.0, 25.0}) {
    o.fitted_pass = pass;
    const ViewCamera v = arc_camera(deg);  // with the lens's distortion
    DrawStats st;
    const ImageU8 drawn = rgb(draw(g, v, o, &st));
    EXPECT_EQ(st.fitted_on_cpu, pass == DrawOptions::FittedPass::kCpu);
    EXPECT_EQ(st.selection.drawn, splats.size());
    const std::array<float, 3> bg{kBackground[0] / 255.f, kBackground[1] / 255.f, kBackground[2] / 255.f};
    const ImageF cpu = render_splats(splats, 4, v.K, v.world_from_camera, bg, nullptr, 0, filter);
    ImageU8 ref(cpu.width, cpu.height, 3);
    for (size_t i = 0; i < cpu.data.size(); ++i) ref.data[i] = uint8_t(std::lround(std::clamp(cpu.data[i], 0.f, 1.f) * 255));
    const double p = *psnr(drawn, ref);
    EXPECT_GT(p, 40.0) << "at " << deg << " degrees, " << (st.fitted_on_cpu ? "cpu" : "gl");
    if (st.fitted_on_cpu) {
      EXPECT_GT(p, 50.0) << "at " << deg << " degrees: the same image formation, rounded once";
    }
    if (sigma_voxels < 0.1f) {  // footprints under a pixel: the filter is not a no-op here
      const ImageF other = render_splats(splats, 4, v.K, v.world_from_camera, bg, nullptr, 0, filter > 0 ? 0.f : 0.3f);
      ImageU8 o8(other.width, other.height, 3);
      for (size_t i = 0; i < other.data.size(); ++i) o8.data[i] = uint8_t(std::lround(std::clamp(other.data[i], 0.f, 1.f) * 255));
      EXPECT_LT(*psnr(o8, ref), 35.0) << "at " << deg << " degrees";
    }
  }
  }
}

TEST(Fitted, AModelWithoutTexturesDrawsOnlyItsFit) {
  TestModel t = make_model("fitted_only", kArc);
  put_splats(t.model, square_splats());
  for (auto& c : t.model.cameras) c.texture.clear();
  ASSERT_TRUE(save_model(t.dir, t.model));
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  EXPECT_EQ(g.renderer->texture_bytes(), 0u);
  auto fb = Framebuffer::create(160, 120);
  ASSERT_TRUE(fb);
  DrawOptions o = background_options();
  auto bb = g.renderer->draw(arc_camera(0), o, *fb);
  ASSERT_FALSE(bb);
  EXPECT_NE(bb.error().message.find("fitted"), std::string::npos) << bb.error().message;
  o.geometry = DrawOptions::Geometry::kSplats;
  EXPECT_TRUE(g.renderer->draw(arc_camera(0), o, *fb));
}


// A fitted model's view never reads the photos: the camera textures (and
// the facets' hierarchy, the meshes) are loaded when billboards are first
// drawn, and the fitted image is the same either way.
TEST(Fitted, CameraTexturesLoadOnlyWhenBillboardsAreDrawn) {
  TestModel t = make_model("fitted_lazy", kArc);
  put_splats(t.model, square_splats());
  ASSERT_TRUE(save_model(t.dir, t.model));
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  EXPECT_TRUE(g.renderer->has_textures());
  EXPECT_FALSE(g.renderer->photo_passes_loaded());
  DrawOptions o = background_options();
  o.geometry = DrawOptions::Geometry::kSplats;
  const ImageU8 before = rgb(draw(g, arc_camera(10), o));
  EXPECT_FALSE(g.renderer->photo_passes_loaded());
  EXPECT_EQ(g.renderer->texture_bytes(), 0u);
  o.geometry = DrawOptions::Geometry::kBillboards;
  DrawStats st;
  draw(g, arc_camera(10), o, &st);
  EXPECT_TRUE(g.renderer->photo_passes_loaded());
  EXPECT_GT(g.renderer->texture_bytes(), 0u);
  EXPECT_GT(st.selection.drawn, 0u);
  o.geometry = DrawOptions::Geometry::kSplats;
  EXPECT_EQ(rgb(draw(g, arc_camera(10), o)).data, before.data);
}
// A model keeps its capture's background (white for NeRF-synthetic); render
// draws on it unless asked for another, and a bad one does not load.
TEST(Fitted, RenderDefaultsToTheModelsBackground) {
  TestModel t = make_model("fitted_background", kArc);
  put_splats(t.model, square_splats());
  t.model.background = std::array<float, 3>{1.f, 1.f, 1.f};
  ASSERT_TRUE(save_model(t.dir, t.model));
  auto loaded = load_model(t.dir);
  ASSERT_TRUE(loaded) << loaded.error().message;
  ASSERT_TRUE(loaded->background);
  EXPECT_EQ(*loaded->background, (std::array<float, 3>{1.f, 1.f, 1.f}));
  ASSERT_TRUE(save_view_file(t.dir / "view.json", arc_camera(0)));
  RenderJob job;
  job.model = t.dir;
  job.view_file = t.dir / "view.json";
  job.draw.geometry = DrawOptions::Geometry::kSplats;
  auto corner = [&](const RenderJob& j) {
    auto r = run_render_job(j);
    EXPECT_TRUE(r) << (r ? "" : r.error().message);
    auto img = read_image_u8(j.out);
    return img ? std::array<int, 3>{img->at(0, 0, 0), img->at(0, 0, 1), img->at(0, 0, 2)} : std::array<int, 3>{-1, -1, -1};
  };
  job.out = t.dir / "default.png";
  EXPECT_EQ(corner(job), (std::array<int, 3>{255, 255, 255}));
  job.out = t.dir / "asked.png";
  job.background = std::array<float, 3>{0.f, 0.f, 0.f};
  EXPECT_EQ(corner(job), (std::array<int, 3>{0, 0, 0}));
  std::string doc = *read_file(t.dir / "model.json");
  const auto at = doc.find("\"background\"");
  ASSERT_NE(at, std::string::npos);
  doc.insert(doc.find('[', at) + 1, "2.0, ");
  ASSERT_TRUE(write_file_atomic(t.dir / "model.json", doc));
  auto bad = load_model(t.dir);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("background"), std::string::npos) << bad.error().message;
}

// The backdrop plate lies under whatever is drawn: colour + (1 - alpha) x
// plate, the alpha (what the model covers) unchanged, for the fit in both
// passes, the billboards and the patch mesh; render puts it behind a frame
// of the model's own capture and not behind an arbitrary pose, and a plate
// of another size does not load.
TEST(Fitted, TheBackdropPlateLiesUnderTheModel) {
  TestModel t = make_model("backdrop_plate", kArc);
  put_splats(t.model, square_splats());
  ASSERT_TRUE(save_model(t.dir, t.model));
  Gl g = open(t);
  ASSERT_TRUE(g.renderer);
  const ViewCamera v = arc_camera(7);
  ImageU8 plate(v.K.width, v.K.height, 3);
  for (int y = 0; y < plate.height; ++y)
    for (int x = 0; x < plate.width; ++x)
      for (int c = 0; c < 3; ++c) plate.at(x, y, c) = uint8_t((x * 2 + y * (c + 1) + 60 * c) % 256);
  using G = DrawOptions::Geometry;
  using P = DrawOptions::FittedPass;
  for (auto [geometry, pass] : {std::pair{G::kSplats, P::kGl}, std::pair{G::kSplats, P::kCpu}, std::pair{G::kBillboards, P::kAuto},
                                std::pair{G::kMesh, P::kAuto}}) {
    if (geometry == G::kMesh && !g.renderer->has_mesh()) continue;
    DrawOptions o;  // black behind
    o.geometry = geometry;
    o.fitted_pass = pass;
    const ImageU8 bare = draw(g, v, o);
    o.backdrop = &plate;
    DrawStats st;
    const ImageU8 on = draw(g, v, o, &st);
    EXPECT_TRUE(st.backdrop_drawn);
    int worst = 0;
    size_t covered = 0, open = 0;
    for (size_t i = 0; i < plate.pixels(); ++i) {
      const int a = bare.data[i * 4 + 3];
      covered += a >= 128, open += a == 0;
      EXPECT_EQ(on.data[i * 4 + 3], a);
      for (size_t c = 0; c < 3; ++c) {
        const double want = bare.data[i * 4 + c] + (255 - a) / 255.0 * plate.data[i * 3 + c];
        worst = std::max(worst, int(std::lround(std::abs(on.data[i * 4 + c] - std::min(255.0, want)))));
      }
    }
    EXPECT_LE(worst, 2) << geometry_name(geometry);
    EXPECT_GT(covered, plate.pixels() / 20) << geometry_name(geometry);
    EXPECT_GT(open, plate.pixels() / 5) << geometry_name(geometry);
  }
  // Through the render job: the model's own camera 0 on the plate, a pose
  // from a file on the background colour.
  ASSERT_TRUE(write_image(t.dir / "backdrop.png", plate));
  t.model.backdrop = "backdrop.png";
  t.model.cameras[0].session_frame = 0;
  ASSERT_TRUE(save_model(t.dir, t.model));
  RenderJob job;
  job.model = t.dir;
  job.view = 0;
  job.draw.geometry = G::kSplats;
  job.out = t.dir / "own.png";
  auto r = run_render_job(job);
  ASSERT_TRUE(r) << r.error().message;
  auto own = read_image_u8(job.out);
  ASSERT_TRUE(own);
  EXPECT_EQ(own->at(0, 0, 1), plate.at(0, 0, 1));
  EXPECT_EQ(own->at(3, 1, 2), plate.at(3, 1, 2));
  // Billboards at that camera itself: behind the object its own photo (the
  // camera texture), not the plate; the fit has no photos to draw from.
  EXPECT_EQ(r->report.counts.count("backdrop_from_the_cameras_own_photo"), 0u);
  job.draw.geometry = G::kBillboards;
  job.out = t.dir / "own_billboards.png";
  r = run_render_job(job);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->report.counts.count("backdrop_from_the_cameras_own_photo"), 1u);
  auto own_bb = read_image_u8(job.out);
  auto tex = read_rgbaz(t.dir / t.model.cameras[0].texture);
  ASSERT_TRUE(own_bb && tex);
  size_t open_px = 0;
  for (int y = 0; y < tex->rgba.height; ++y)
    for (int x = 0; x < tex->rgba.width; ++x) {
      if (tex->rgba.at(x, y, 3)) continue;  // the object in that photo
      ++open_px;
      for (int c = 0; c < 3; ++c) ASSERT_NEAR(own_bb->at(x, y, c), tex->rgba.at(x, y, c), 1) << x << "," << y;
    }
  EXPECT_GT(open_px, tex->rgba.pixels() / 5);
  job.draw.geometry = G::kSplats;
  ASSERT_TRUE(save_view_file(t.dir / "view.json", ViewCamera{t.model.cameras[0].intrinsics, t.model.cameras[0].world_from_camera}));
  job.view.reset();
  job.view_file = t.dir / "view.json";
  job.out = t.dir / "pose.png";
  r = run_render_job(job);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->report.skipped.count("backdrop_plate_not_this_view"), 1u);
  auto pose = read_image_u8(job.out);
  ASSERT_TRUE(pose);
  EXPECT_EQ(pose->at(3, 1, 2), 0);
  ASSERT_TRUE(write_image(t.dir / "backdrop.png", ImageU8(8, 8, 3)));
  auto loaded = load_model(t.dir);
  ASSERT_TRUE(loaded);
  auto bad = load_backdrop(*loaded, t.dir);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("8x8"), std::string::npos) << bad.error().message;
}

TEST(ViewFile, RoundTripsAndRejectsNaN) {
  const fs::path p = fs::path(testing::TempDir()) / "s2r_view.json";
  const ViewCamera v = arc_camera(12);
  ASSERT_TRUE(save_view_file(p, v));
  auto back = load_view_file(p);
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_TRUE(back->world_from_camera.isApprox(v.world_from_camera, 1e-12));
  EXPECT_EQ(back->K.width, v.K.width);
  auto text = read_file(p);
  ASSERT_TRUE(text);
  std::string bad = *text;
  const auto at = bad.find("\"world_from_camera\"");
  ASSERT_NE(at, std::string::npos);
  const auto num = bad.find_first_of("-0123456789", bad.find('[', at));
  bad.replace(num, bad.find_first_of(",]", num) - num, "NaN");
  ASSERT_TRUE(write_file_atomic(p, bad));
  auto r = load_view_file(p);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("s2r_view.json"), std::string::npos) << r.error().message;
}

TEST(Viewer, WindowShowsTheHeadlessImageUnderXvfb) {
  XServer x;
  if (!x.ok()) GTEST_SKIP() << x.reason();
  const TestModel t = make_model("viewer", kArc);
  const int W = 200, H = 150;
  ImageU8 headless;
  {
    Gl g = open(t);
    ASSERT_TRUE(g.renderer);
    headless = rgb(draw(g, default_orbit_view(t.model, W, H), DrawOptions{}));
  }
  ViewerOptions o;
  o.model = t.dir;
  o.width = W, o.height = H;
  o.frames = 1;
  o.screenshot = t.dir / "screenshot.png";
  auto r = run_viewer(o);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->counts.at("frames"), 1);
  EXPECT_EQ(r->counts.at("status_line_on_screen"), 1);
  EXPECT_NE(std::get<std::string>(r->params.at("status_line")).find("facets 1681 drawn"), std::string::npos);
  auto shot = read_image_u8(o.screenshot);
  ASSERT_TRUE(shot) << shot.error().message;
  ASSERT_TRUE(shot->same_shape(headless));
  size_t differ = 0, drawn = 0;
  for (size_t i = 0; i < headless.data.size(); ++i) differ += shot->data[i] != headless.data[i];
  for (size_t i = 0; i < headless.pixels(); ++i) drawn += headless.data[i * 3] || headless.data[i * 3 + 1];
  EXPECT_EQ(differ, 0u);
  EXPECT_GT(drawn, 1000u);
}

}  // namespace
}  // namespace s2r
