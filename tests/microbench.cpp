// Google Benchmark micro-benchmarks (not run by CTest; timing is never asserted):
//   build/tests/s2r_microbench [--benchmark_filter=...]
// Each pair has a peer in the same run: compare ratios, not absolute times.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <filesystem>
#include <optional>

#include "capture/synth_rig.h"
#include "core/camera_model.h"
#include "core/image_metrics.h"
#include "core/mesh.h"
#include "core/paths.h"
#include "core/progress.h"
#include "reconstruct/camera_depth.h"
#include "reconstruct/model.h"
#include "reconstruct/reconstruct_job.h"
#include "reconstruct/splat_composite.h"
#include "reconstruct/splat_fit.h"
#include "reconstruct/splat_raster.h"
#include "render/raytrace_job.h"

namespace s2r {
namespace {

void BM_RigRender(benchmark::State& state) {
  SynthOptions o;
  o.scene = "blob";
  o.width = static_cast<int>(state.range(0));
  o.height = o.width * 3 / 4;
  o.threads = static_cast<int>(state.range(1));
  auto rig = SynthRig::create(o);
  if (!rig) {
    state.SkipWithError(rig.error().message.c_str());
    return;
  }
  int view = 0;
  for (auto _ : state) benchmark::DoNotOptimize((*rig)->render(view++ % o.views).rays);
  state.SetItemsProcessed(state.iterations() * int64_t(o.width) * o.height);
}
BENCHMARK(BM_RigRender)->Args({320, 1})->Args({320, 2})->Unit(benchmark::kMillisecond);

// Mochizuki and Makino's scene C (8 mirror bunnies on the front screen) rendered whole
// with every object held at one mesh level (0 = N_max): what a coarser level
// saves per ray. Peer: level 0 in the same run.
// Scene C with `levels` mesh levels per bunny; skips the benchmark on failure.
std::optional<RtScene> scene_c(benchmark::State& state, int levels) {
  auto bunny = read_ply_mesh(data_dir() / "stanford_bunny" / "bun_zipper.ply");
  SeedSceneOptions so;
  so.scene = 'C';
  so.levels = levels;
  auto scene = bunny ? seed_scene(*bunny, so) : Result<RtScene>(std::unexpected(bunny.error()));
  if (!scene) {
    state.SkipWithError(scene.error().message.c_str());
    return std::nullopt;
  }
  return std::move(*scene);
}

void BM_RaytraceMeshLevel(benchmark::State& state) {
  auto scene = scene_c(state, 6);
  if (!scene) return;
  const int level = static_cast<int>(state.range(0));
  size_t triangles = 0;
  for (auto& o : scene->objects) {
    const int k = std::min<int>(level, static_cast<int>(o.mesh.levels.size()) - 1);
    o.mesh.levels = {o.mesh.levels[k]};
    triangles = o.mesh.levels[0].size();
  }
  auto rt = RayTracer::create(std::move(*scene));
  const auto screens = cave_screens(256);
  for (auto _ : state) benchmark::DoNotOptimize(render_layout(**rt, screens, cave_default_eye(), {}).stats.primary);
  state.counters["triangles_per_object"] = static_cast<double>(triangles);
}
BENCHMARK(BM_RaytraceMeshLevel)->DenseRange(0, 5)->Unit(benchmark::kMillisecond);

// Scene C, gaze forward: the full render (0), visual-field LOD (1), and LOD
// with one mesh level only (2: budgets and skipped pixels, no mesh switching).
void BM_RaytraceFieldLod(benchmark::State& state) {
  auto scene = scene_c(state, state.range(0) == 2 ? 1 : 6);
  if (!scene) return;
  auto rt = RayTracer::create(std::move(*scene));
  TraceOptions o;
  o.field_lod = state.range(0) > 0;
  o.gaze = *EyeFrame::look({0, 0, -1});
  const auto screens = cave_screens(256);
  for (auto _ : state) benchmark::DoNotOptimize(render_layout(**rt, screens, cave_default_eye(), o).stats.primary);
}
BENCHMARK(BM_RaytraceFieldLod)->DenseRange(0, 2)->Unit(benchmark::kMillisecond);

void BM_Ssim(benchmark::State& state) {
  ImageU8 a(640, 480, 3), b(640, 480, 3);
  for (size_t i = 0; i < a.data.size(); ++i) {
    a.data[i] = static_cast<uint8_t>(i * 31);
    b.data[i] = static_cast<uint8_t>(i * 31 + (i % 7));
  }
  for (auto _ : state) benchmark::DoNotOptimize(*ssim(a, b));
}
BENCHMARK(BM_Ssim)->Unit(benchmark::kMillisecond);

void BM_Psnr(benchmark::State& state) {  // the cheap peer of SSIM
  ImageU8 a(640, 480, 3), b(640, 480, 3, 3);
  for (auto _ : state) benchmark::DoNotOptimize(*psnr(a, b));
}
BENCHMARK(BM_Psnr)->Unit(benchmark::kMillisecond);

// A 640 x 480 camera with moderate radial and tangential distortion.
Intrinsics bench_lens() {
  Intrinsics k;
  k.width = 640; k.height = 480; k.fx = 600; k.fy = 600; k.cx = 320; k.cy = 240;
  k.dist = {-0.12, 0.05, 0.0008, -0.0005, 0};
  return k;
}

void BM_Undistort(benchmark::State& state) {
  const Intrinsics k = bench_lens();
  double x = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(k.ray({x, 0.75 * x}));
    x = x > 639 ? 0 : x + 1;
  }
}
BENCHMARK(BM_Undistort);

// The same pixels, each started from its left neighbour's answer: the ratio
// to BM_Undistort is the saving.
void BM_UndistortFromNeighbour(benchmark::State& state) {
  const Intrinsics k = bench_lens();
  double x = 0;
  Eigen::Vector2d previous = Eigen::Vector2d::Constant(std::nan(""));
  for (auto _ : state) {
    const auto xn = k.undistort({(x - k.cx) / k.fx, (0.75 * x - k.cy) / k.fy}, previous);
    benchmark::DoNotOptimize(xn);
    previous = x > 639 ? Eigen::Vector2d::Constant(std::nan("")) : *xn;
    x = x > 639 ? 0 : x + 1;
  }
}
BENCHMARK(BM_UndistortFromNeighbour);

// The same pixels, each started from its two previous neighbours' answers
// extrapolated, as the rasterizer makes its pixel rays.
void BM_UndistortExtrapolated(benchmark::State& state) {
  const Intrinsics k = bench_lens();
  double x = 0;
  const Eigen::Vector2d none = Eigen::Vector2d::Constant(std::nan(""));
  Eigen::Vector2d p1 = none, p2 = none;
  for (auto _ : state) {
    const Eigen::Vector2d start = p2.allFinite() ? Eigen::Vector2d(2 * p1 - p2) : p1;
    const auto xn = k.undistort({(x - k.cx) / k.fx, (0.75 * x - k.cy) / k.fy}, start);
    benchmark::DoNotOptimize(xn);
    p2 = x > 639 ? none : p1;
    p1 = x > 639 ? none : *xn;
    x = x > 639 ? 0 : x + 1;
  }
}
BENCHMARK(BM_UndistortExtrapolated);

// A camera's distance image of a 37k-triangle sphere through a distorted
// 640 x 480 lens: /0 the rasterizer (reconstruct's), /1 Embree's ray casts
// (its reference), one thread each. The pixel rays are made before timing.
void BM_CameraDepth(benchmark::State& state) {
  Mesh m;
  const int rings = 96, segments = 192;
  const float radius = 0.05f;
  for (int i = 0; i <= rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const float th = 3.14159265f * float(i) / float(rings), ph = 6.2831853f * float(j) / float(segments);
      m.vertices.push_back(radius * Eigen::Vector3f(std::sin(th) * std::cos(ph), std::cos(th), std::sin(th) * std::sin(ph)));
    }
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const int a = i * segments + j, b = i * segments + (j + 1) % segments;
      m.faces.push_back({a, b, b + segments});
      m.faces.push_back({a, b + segments, a + segments});
    }
  const Intrinsics k = bench_lens();
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translation() = Eigen::Vector3d(0.01, -0.005, -0.3);  // looking along +z at the sphere
  if (state.range(0) == 0) {
    const MeshRasterizer raster(m);
    benchmark::DoNotOptimize(raster.distance_image(k, pose));  // makes the rays it needs
    for (auto _ : state) benchmark::DoNotOptimize(raster.distance_image(k, pose));
  } else {
    auto caster = MeshRaycaster::create(m);
    if (!caster) {
      state.SkipWithError("Embree device");
      return;
    }
    benchmark::DoNotOptimize((*caster)->distance_image(k, pose, 1));
    for (auto _ : state) benchmark::DoNotOptimize((*caster)->distance_image(k, pose, 1));
  }
}
BENCHMARK(BM_CameraDepth)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// The whole reconstruct job as `s2r bench reconstruct` times it (rig bunny,
// 24 views, depth geometry, uniform facets, no textures) at w = arg / 10 mm,
// in process: run under perf to see where a build's time goes. The session is
// made once, in a temporary folder. Its peer is Open3D, in `s2r bench`.
// The folder goes when the process ends.
struct BenchDir {
  std::filesystem::path path = std::filesystem::temp_directory_path() / ("s2r_microbench_" + std::to_string(::getpid()));
  ~BenchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
};

void BM_ReconstructJob(benchmark::State& state) {
  static const BenchDir dir;
  static const std::filesystem::path session = [] {
    SynthOptions so;
    so.views = 24;
    so.seed = 3;
    if (!synth_session(so, dir.path / "session")) return std::filesystem::path();
    // Without the true mesh the job skips its check against the truth, which
    // the build's seconds leave out anyway: the profile shows the build alone.
    std::filesystem::remove(dir.path / "session" / "ground_truth" / "geometry.ply");
    return dir.path / "session";
  }();
  if (session.empty()) {
    state.SkipWithError("cannot make the rig session");
    return;
  }
  ReconstructJob job;
  job.session = session;
  job.out = session.parent_path() / "model";
  job.voxel_m = 1e-4 * double(state.range(0));
  job.geometry = Geometry::depth;
  job.per_region = false;
  job.textures = false;
  set_progress_enabled(false);
  for (auto _ : state) {
    auto r = run_reconstruct_job(job);
    if (!r) {
      state.SkipWithError(r.error().message.c_str());
      return;
    }
    state.SetIterationTime(r->seconds);
    // Each step's seconds too, averaged over the iterations.
    for (const auto& [key, value] : r->report.counts)
      if (key.starts_with("seconds_")) state.counters[key.substr(8)] += value;
  }
  for (auto& [key, counter] : state.counters) counter.flags = benchmark::Counter::kAvgIterations;
}
BENCHMARK(BM_ReconstructJob)->Arg(15)->Arg(30)->Arg(60)->UseManualTime()->Unit(benchmark::kMillisecond);

// The display compositor on a fitted model's facets (S2R_SPLAT_MODEL: a
// model folder with a fit, e.g. lego's from `s2r bench views`), from its
// first camera scaled to 800 pixels wide; argument: lanes (4, or 0 for the
// widest the processor has). Counters: each phase's milliseconds.
void BM_SplatComposite(benchmark::State& state) {
  static const std::optional<Model> model = []() -> std::optional<Model> {
    const char* dir = std::getenv("S2R_SPLAT_MODEL");
    if (!dir) return std::nullopt;
    auto m = load_model(dir);
    if (!m || m->splats.empty() || m->cameras.empty()) return std::nullopt;
    order_splats_spatially(m->splats, m->splat_layout.stride());
    return std::move(*m);
  }();
  if (!model) {
    state.SkipWithError("S2R_SPLAT_MODEL: not a fitted model folder");
    return;
  }
  Intrinsics K = model->cameras[0].intrinsics;
  const double s = 800.0 / K.width;
  K.width = 800, K.height = int(std::lround(K.height * s));
  K.fx *= s, K.fy *= s, K.cx = (K.cx + 0.5) * s - 0.5, K.cy = (K.cy + 0.5) * s - 0.5;
  SplatCompositor c;
  c.set_lanes(int(state.range(0)));
  c.set_pixel_filter(model->splat_layout.pixel_filter_px2);
  std::vector<float> rgba;
  int view = 0;
  for (auto _ : state) {
    SplatCompositeStats st;
    const auto& cam = model->cameras[size_t(view++) % model->cameras.size()];
    c.composite(model->splats, model->splat_layout.coeffs(), K, cam.world_from_camera, 0.01, rgba, 0, &st);
    state.counters["project_ms"] += st.ms_project, state.counters["bin_ms"] += st.ms_sort,
        state.counters["composite_ms"] += st.ms_composite;
  }
  for (auto& [key, counter] : state.counters) counter.flags = benchmark::Counter::kAvgIterations;
}
BENCHMARK(BM_SplatComposite)->Arg(4)->Arg(0)->Unit(benchmark::kMillisecond);

// A fitted model's facets (S2R_SPLAT_MODEL, as above) as the fit holds them,
// and its first cameras scaled to 800 pixels wide.
struct FitInput {
  std::vector<Splat> splats;
  int coeffs = 1;
  float pixel_filter = 0;
  std::vector<std::pair<Intrinsics, Eigen::Isometry3d>> cameras;
};
const FitInput* fit_input() {
  static const std::optional<FitInput> input = []() -> std::optional<FitInput> {
    const char* dir = std::getenv("S2R_SPLAT_MODEL");
    if (!dir) return std::nullopt;
    auto m = load_model(dir);
    if (!m || m->splats.empty() || m->cameras.empty()) return std::nullopt;
    FitInput in;
    const int stride = m->splat_layout.stride();
    in.coeffs = m->splat_layout.coeffs();
    in.pixel_filter = m->splat_layout.pixel_filter_px2;
    in.splats.resize(m->splat_count());
    for (size_t i = 0; i < in.splats.size(); ++i) {
      const float* r = &m->splats[i * size_t(stride)];
      Splat& s = in.splats[i];
      s.anchor = Eigen::Vector3f(r[0], r[1], r[2]);
      s.voxel = 1;
      s.log_sigma = std::log(r[3]);
      s.opacity_logit = std::log(r[4] / (1.f - r[4]));
      for (int k = 0; k < 3 * in.coeffs; ++k) s.sh[size_t(k)] = r[5 + k];
    }
    for (size_t v = 0; v < std::min<size_t>(4, m->cameras.size()); ++v) {
      Intrinsics K = m->cameras[v].intrinsics;
      const double s = 800.0 / K.width;
      K.width = 800, K.height = int(std::lround(K.height * s));
      K.fx *= s, K.fy *= s, K.cx = (K.cx + 0.5) * s - 0.5, K.cy = (K.cy + 0.5) * s - 0.5;
      in.cameras.emplace_back(K, m->cameras[v].world_from_camera);
    }
    return in;
  }();
  return input ? &*input : nullptr;
}

// One step's projection in the fit (every facet projected, sorted by depth,
// listed per tile) into a frame whose storage is reused, as the fit does.
void BM_SplatFitProject(benchmark::State& state) {
  const FitInput* in = fit_input();
  if (!in) {
    state.SkipWithError("S2R_SPLAT_MODEL: not a fitted model folder");
    return;
  }
  fit_detail::SplatFrame f;
  size_t view = 0;
  double entries = 0;
  for (auto _ : state) {
    const auto& [K, T] = in->cameras[view++ % in->cameras.size()];
    fit_detail::project_into(f, in->splats, in->coeffs, K, T, 0, in->pixel_filter);
    benchmark::DoNotOptimize(f.tile_list.data());
    entries += double(f.tile_list.size());
  }
  state.counters["tile_entries"] = entries / double(std::max<size_t>(1, view));  // (facet, tile) pairs a view
}
BENCHMARK(BM_SplatFitProject)->Unit(benchmark::kMillisecond);

// One step of the fit's rasterizer (forward and back through every tile,
// the gradient of the squared error) at 800 x 800, for a fitted model's
// facets at its first cameras; the argument is the lanes (1: the scalar
// reference, 4, 0: the widest this processor has).
void BM_SplatFitRaster(benchmark::State& state) {
  static const std::optional<std::vector<fit_detail::SplatFrame>> frames = []() -> std::optional<std::vector<fit_detail::SplatFrame>> {
    const FitInput* in = fit_input();
    if (!in) return std::nullopt;
    std::vector<fit_detail::SplatFrame> out;
    for (const auto& [K, T] : in->cameras) out.push_back(fit_detail::project(in->splats, in->coeffs, K, T, 0, in->pixel_filter));
    return out;
  }();
  if (!frames) {
    state.SkipWithError("S2R_SPLAT_MODEL: not a fitted model folder");
    return;
  }
  ImageU8 grey(800, 800, 3);
  std::fill(grey.data.begin(), grey.data.end(), uint8_t(128));
  const float white[3] = {1, 1, 1};
  std::vector<std::vector<fit_detail::Grad>> grads;
  size_t view = 0;
  for (auto _ : state) {
    const auto& f = (*frames)[view++ % frames->size()];
    benchmark::DoNotOptimize(fit_detail::forward_backward(f, grey, {white}, 1.f, 0, &grads, {}, int(state.range(0))));
  }
}
BENCHMARK(BM_SplatFitRaster)->Arg(1)->Arg(4)->Arg(0)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace s2r

BENCHMARK_MAIN();
