// Google Benchmark micro-benchmarks (not run by CTest; timing is never asserted):
//   build/tests/s2r_microbench [--benchmark_filter=...]
// Each pair has a peer in the same run: compare ratios, not absolute times.
#include <benchmark/benchmark.h>

#include "capture/synth_rig.h"
#include "core/camera_model.h"
#include "core/image_metrics.h"

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

void BM_Undistort(benchmark::State& state) {
  Intrinsics k;
  k.width = 640; k.height = 480; k.fx = 600; k.fy = 600; k.cx = 320; k.cy = 240;
  k.dist = {-0.12, 0.05, 0.0008, -0.0005, 0};
  double x = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(k.ray({x, 0.75 * x}));
    x = x > 639 ? 0 : x + 1;
  }
}
BENCHMARK(BM_Undistort);

}  // namespace
}  // namespace s2r

BENCHMARK_MAIN();
