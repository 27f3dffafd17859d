// The environment map's accuracy check, preview and `s2r envmap`.
#include <algorithm>
#include <cmath>
#include <random>

#include <spdlog/fmt/fmt.h>

#include "core/image_io.h"
#include "core/parallel.h"
#include "render/envmap.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

void add(EnvmapBandError& b, const Eigen::Vector3f& got, const Eigen::Vector3d& ref) {
  double display = 0, linear = 0;
  for (int c = 0; c < 3; ++c) {
    const double d = std::abs(std::clamp<double>(got[c], 0, 1) - std::clamp(ref[c], 0.0, 1.0));
    const double l = std::abs(got[c] - ref[c]);
    display += d / 3;
    linear += l / 3;
    b.max_display = std::max(b.max_display, d);
    b.max_linear = std::max(b.max_linear, l);
    b.max_relative = std::max(b.max_relative, l / std::max(ref[c], 1.0 / 255));
  }
  b.mean_display += display;  // sums until finished
  b.mean_linear += linear;
  ++b.count;
}

void merge(EnvmapBandError& into, const EnvmapBandError& b) {
  into.count += b.count;
  into.mean_display += b.mean_display;
  into.mean_linear += b.mean_linear;
  into.max_display = std::max(into.max_display, b.max_display);
  into.max_linear = std::max(into.max_linear, b.max_linear);
  into.max_relative = std::max(into.max_relative, b.max_relative);
}

void finish(EnvmapBandError& b) {
  if (b.count == 0) return;
  b.mean_display /= b.count;
  b.mean_linear /= b.count;
}

}  // namespace

Result<EnvmapAccuracy> envmap_accuracy(const EnvironmentMap& map, const Panorama& pano, int samples, int bands,
                                       bool interpolated, unsigned seed, int threads) {
  if (samples < 1 || bands < 1) return fail("envmap accuracy: samples and bands must be >= 1");
  const int s = map.size();
  // The points first (deterministic for a seed), then the brute force in parallel.
  struct Point {
    int band;
    Eigen::Vector3d t;
    Eigen::Vector3f got;
  };
  std::vector<Point> points;
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> voxel(0, s - 1);
  std::normal_distribution<double> gauss;
  std::uniform_real_distribution<double> unit(0, 1);
  for (int n = 0; n < samples; ++n) {
    const int band = n % bands;
    const double lo = static_cast<double>(band) / bands, hi = static_cast<double>(band + 1) / bands;
    Point p{band, {}, {}};
    if (interpolated) {
      Eigen::Vector3d u(gauss(rng), gauss(rng), gauss(rng));
      while (u.norm() < 1e-9) u = {gauss(rng), gauss(rng), gauss(rng)};
      // uniform in volume within the band: r^3 uniform
      const double r = std::cbrt(lo * lo * lo + unit(rng) * (hi * hi * hi - lo * lo * lo));
      p.t = u.normalized() * std::max(r, 1e-6);
      p.got = map.lookup(p.t);
    } else {
      bool found = false;
      for (int tries = 0; tries < 100000 && !found; ++tries) {
        const int i = voxel(rng), j = voxel(rng), k = voxel(rng);
        const Eigen::Vector3d t = map.voxel_centre(i, j, k);
        const double r = t.norm();
        if (r > 0 && r >= lo && (r < hi || (band == bands - 1 && r <= 1))) {
          p.t = t;
          p.got = map.voxel(i, j, k);
          found = true;
        }
      }
      if (!found) continue;  // a band thinner than a voxel holds no centre
    }
    points.push_back(p);
  }
  Stopwatch clock;
  std::vector<Eigen::Vector3d> ref(points.size());
  std::vector<std::string> errors(points.size());
  parallel_for(static_cast<int>(points.size()), threads, [&](int n) {
    const double r = points[n].t.norm();
    auto v = phong_lobe(pano, points[n].t, envmap_exponent(r, s, map.intensity_levels()));
    if (v) ref[n] = *v;
    else errors[n] = v.error().message;
  });
  EnvmapAccuracy acc;
  acc.reference_seconds = clock.seconds();
  for (const auto& e : errors)
    if (!e.empty()) return fail("envmap accuracy: " + e);
  acc.bands.resize(bands);
  for (int b = 0; b < bands; ++b) {
    acc.bands[b].lambda_lo = static_cast<double>(b) / bands;
    acc.bands[b].lambda_hi = static_cast<double>(b + 1) / bands;
  }
  for (size_t n = 0; n < points.size(); ++n) add(acc.bands[points[n].band], points[n].got, ref[n]);
  acc.all.lambda_lo = 0;
  acc.all.lambda_hi = 1;
  for (auto& b : acc.bands) merge(acc.all, b);
  for (auto& b : acc.bands) finish(b);
  finish(acc.all);
  return acc;
}

ImageU8 envmap_preview(const EnvironmentMap& map, int width) {
  const int h = width / 2;
  const double lambdas[] = {1.0, 0.75, 0.5, 0.25, 0.0};
  ImageU8 out(width, h * 5, 3);
  for (int band = 0; band < 5; ++band)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < width; ++x) {
        const Eigen::Vector3d d = equirect_direction(x, y, width, h);
        // lambda = 0 is the one voxel at the centre: show the nearly uniform lobes just outside it.
        const Eigen::Vector3f v = map.lookup(d * std::max(lambdas[band], 1.0 / map.size()));
        for (int c = 0; c < 3; ++c)
          out.at(x, band * h + y, c) = static_cast<uint8_t>(std::lround(255 * std::pow(std::clamp(v[c], 0.f, 1.f), 1 / 2.2f)));
      }
  return out;
}

Result<Report> run_envmap_job(const EnvmapJob& job) {
  Stopwatch clock;
  Report report;
  report.stage = "envmap";
  auto pano = load_panorama(job.panorama, job.clamp, &report.warnings);
  if (!pano) return std::unexpected(pano.error());
  EnvmapStats stats;
  auto map = build_envmap(*pano, job.options, &stats);
  if (!map) return std::unexpected(map.error());
  if (auto w = map->save(job.out, job.panorama.filename().string()); !w) return std::unexpected(w.error());
  std::error_code ec;
  stats.file_bytes = fs::file_size(job.out, ec);
  const fs::path preview = fs::path(job.out).replace_extension(".png");
  if (auto w = write_image(preview, envmap_preview(*map, 512)); !w) return std::unexpected(w.error());

  report.counts["voxels"] = static_cast<double>(stats.voxels);
  report.counts["samples"] = stats.samples;
  report.counts["samples_per_voxel"] = stats.samples / std::max<size_t>(1, stats.voxels);
  report.counts["memory_bytes"] = static_cast<double>(stats.memory_bytes);
  report.counts["file_bytes"] = static_cast<double>(stats.file_bytes);
  report.counts["build_seconds"] = stats.seconds;
  report.counts["pyramid_seconds"] = stats.pyramid_seconds;
  for (size_t l = 0; l < stats.voxels_per_level.size(); ++l)
    report.counts[fmt::format("voxels_at_pyramid_level_{}", l)] = static_cast<double>(stats.voxels_per_level[l]);
  report.skipped["voxels_outside_unit_ball"] = static_cast<double>(stats.voxels_outside);
  report.params["size"] = static_cast<double>(job.options.size);
  report.params["intensity_levels"] = job.options.intensity_levels;
  report.params["threshold"] = job.options.threshold;
  report.params["samples_per_scale"] = job.options.samples_per_scale;
  report.params["exponent_at_lambda_1"] = envmap_exponent(1, job.options.size, job.options.intensity_levels);
  report.params["panorama"] = job.panorama.string();
  report.params["preview"] = preview.string();
  if (job.check > 0) {
    auto acc = envmap_accuracy(*map, *pano, job.check, 4, false, job.seed, job.options.threads);
    if (!acc) return std::unexpected(acc.error());
    report.errors["mean_display_error"] = acc->all.mean_display;
    report.errors["max_display_error"] = acc->all.max_display;
    report.errors["mean_linear_error"] = acc->all.mean_linear;
    report.errors["max_relative_error"] = acc->all.max_relative;
    for (const auto& b : acc->bands)
      report.errors[fmt::format("mean_display_error_lambda_{:.2f}_{:.2f}", b.lambda_lo, b.lambda_hi)] = b.mean_display;
    report.counts["checked_voxels"] = static_cast<double>(acc->all.count);
    report.counts["brute_force_seconds"] = acc->reference_seconds;
    report.counts["brute_force_seconds_per_voxel"] = acc->reference_seconds / std::max<size_t>(1, acc->all.count);
  }
  report.seconds = clock.seconds();
  return report;
}

}  // namespace s2r
