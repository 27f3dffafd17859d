// s2r export web (render/web_export.h).
#include "render/web_export.h"

#include <unistd.h>

#include <cmath>
#include <cstring>

#include <nlohmann/json.hpp>

#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "reconstruct/model.h"
#include "render/model_renderer.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

json vec3(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

}  // namespace

Result<Report> export_web(const WebExportJob& job) {
  Stopwatch sw;
  Report rep;
  rep.stage = "export";
  rep.params["format"] = std::string("web");
  if (job.background)
    for (float c : *job.background)
      if (!(c >= 0 && c <= 1)) return fail(ErrorCode::invalid, "background: each channel must be in [0, 1]");
  if (auto st = check_new_folder(job.out); !st) return std::unexpected(st.error());
  auto model = load_model(job.model);
  if (!model) return fail_with_context(model.error(), "model");
  if (model->facets.empty()) return fail(ErrorCode::invalid, "model '" + job.model.string() + "' has no facets to draw");

  // Camera textures as s2r render loads them.
  const size_t n = model->cameras.size();
  std::vector<RgbazImage> tex(n);
  std::vector<std::string> errors(n);
  {
    Progress progress("export web: cameras", n);
    parallel_for(static_cast<int>(n), job.threads, [&](int i) {
      const auto& c = model->cameras[size_t(i)];
      if (c.texture.empty()) return;
      auto t = read_rgbaz(job.model / c.texture);
      if (!t) errors[size_t(i)] = t.error().message;
      else {
        tex[size_t(i)] = std::move(*t);
        fill_silhouette_distance(tex[size_t(i)].distance);
      }
    });
    progress.tick(n);
  }
  for (const auto& e : errors)
    if (!e.empty()) return fail(ErrorCode::format, e);
  int W = 0, H = 0, layers = 0;
  std::vector<int> layer(n, -1);
  for (size_t i = 0; i < n; ++i) {
    if (tex[i].rgba.empty()) continue;
    if (tex[i].rgba.channels != 4 || tex[i].distance.width != tex[i].rgba.width || tex[i].distance.height != tex[i].rgba.height)
      return fail(ErrorCode::format, model->cameras[i].texture + ": colour and distance differ in size");
    layer[i] = layers++;
    W = std::max(W, tex[i].rgba.width);
    H = std::max(H, tex[i].rgba.height);
  }
  if (!(job.budget_mib > 0)) return fail(ErrorCode::invalid, "budget_mib: must be > 0");
  // The payload budget: the smallest integer reduction of every camera image that fits.
  int factor = 1;
  const double budget = job.budget_mib * 1048576.0;
  auto bytes_at = [&](int f) { return 8.0 * ((W + f - 1) / f) * double((H + f - 1) / f) * layers; };
  while (bytes_at(factor) > budget && factor < 64) ++factor;
  if (bytes_at(factor) > budget)
    return fail(ErrorCode::invalid, "budget_mib: " + std::to_string(job.budget_mib) + " MiB cannot hold " + std::to_string(layers) +
                                        " camera images even at 1/64 of their size");
  std::vector<Intrinsics> intrinsics(n);
  for (size_t i = 0; i < n; ++i) intrinsics[i] = model->cameras[i].intrinsics;
  if (factor > 1) {
    for (size_t i = 0; i < n; ++i) {
      if (layer[i] < 0) continue;
      const RgbazImage& t = tex[i];
      const int w = (t.rgba.width + factor - 1) / factor, h = (t.rgba.height + factor - 1) / factor;
      RgbazImage r{ImageU8(w, h, 4, 0), ImageF(w, h, 1, 0.f)};
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          int sum[4] = {0, 0, 0, 0}, count = 0;
          float nearest = 0;
          for (int v = y * factor; v < std::min(t.rgba.height, (y + 1) * factor); ++v)
            for (int u = x * factor; u < std::min(t.rgba.width, (x + 1) * factor); ++u) {
              for (int c = 0; c < 4; ++c) sum[c] += t.rgba.at(u, v, c);
              ++count;
              const float d = t.distance.at(u, v);
              if (d > 0 && (nearest == 0 || d < nearest)) nearest = d;
            }
          for (int c = 0; c < 4; ++c) r.rgba.at(x, y, c) = static_cast<uint8_t>((sum[c] + count / 2) / count);
          r.distance.at(x, y) = nearest;
        }
      tex[i] = std::move(r);
      // Pixel centres at integers: pixel x' covers x in [f x', f x' + f - 1].
      Intrinsics& K = intrinsics[i];
      K.fx /= factor;
      K.fy /= factor;
      K.cx = (K.cx + 0.5) / factor - 0.5;
      K.cy = (K.cy + 0.5) / factor - 0.5;
      K.width = w;
      K.height = h;
    }
    W = (W + factor - 1) / factor;
    H = (H + factor - 1) / factor;
    rep.warnings.push_back("camera images reduced to 1/" + std::to_string(factor) + " to fit the " +
                           std::to_string(static_cast<int>(job.budget_mib)) + "-MiB budget");
  }
  rep.counts["camera_image_reduction"] = factor;
  if (layers == 0)
    return fail(ErrorCode::not_found, "model '" + job.model.string() +
                                          "' has no camera images (reconstructed with --no-textures): the web viewer draws billboards from them");
  std::string colour(size_t(W) * H * layers * 4, '\0'), distance(size_t(W) * H * layers * 4, '\0');
  for (size_t i = 0; i < n; ++i) {
    if (layer[i] < 0) continue;
    const auto& t = tex[i];
    for (int y = 0; y < t.rgba.height; ++y) {
      const size_t row = (size_t(layer[i]) * H + y) * W;
      std::memcpy(&colour[row * 4], &t.rgba.data[size_t(y) * t.rgba.width * 4], size_t(t.rgba.width) * 4);
      std::memcpy(&distance[row * 4], &t.distance.data[size_t(y) * t.distance.width], size_t(t.distance.width) * 4);
    }
  }

  json cams = json::array();
  for (size_t i = 0; i < n; ++i) {
    const ModelCamera& c = model->cameras[i];
    const Intrinsics& K = intrinsics[i];
    const Eigen::Matrix4f cfw = c.world_from_camera.inverse().matrix().cast<float>();
    std::vector<float> gpu(cfw.data(), cfw.data() + 16);  // column-major, as GLSL's mat4
    const Eigen::Vector3d centre = c.world_from_camera.translation();
    for (float v : {float(K.fx), float(K.fy), float(K.cx), float(K.cy), float(K.dist[0]), float(K.dist[1]), float(K.dist[2]),
                    float(K.dist[3]), float(K.dist[4]), float(K.width), float(K.height), float(layer[i]), float(centre.x()),
                    float(centre.y()), float(centre.z()), float(camera_field_r2(K))})
      gpu.push_back(v);
    const Eigen::Matrix3d R = c.world_from_camera.linear();
    cams.push_back({{"session_frame", c.session_frame},
                    {"layer", layer[i]},
                    {"K", {{"width", K.width}, {"height", K.height}, {"fx", K.fx}, {"fy", K.fy}, {"cx", K.cx}, {"cy", K.cy},
                           {"dist", {K.dist[0], K.dist[1], K.dist[2], K.dist[3], K.dist[4]}}}},
                    {"centre", vec3(centre)},
                    {"right", vec3(R.col(0))},
                    {"down", vec3(R.col(1))},
                    {"fwd", vec3(R.col(2))},
                    {"gpu", gpu}});
  }
  const DrawOptions d;
  const SelectionOptions so;
  std::string facets(model->facets.size() * sizeof(FacetRecord), '\0');
  std::memcpy(facets.data(), model->facets.data(), facets.size());
  std::string facet_cameras(model->facet_cameras.size() * 4, '\0');
  std::memcpy(facet_cameras.data(), model->facet_cameras.data(), facet_cameras.size());
  const std::pair<const char*, const std::string*> payloads[] = {
      {"facets", &facets}, {"facet_cameras", &facet_cameras}, {"colour", &colour}, {"distance", &distance}};
  json pl = json::array();
  for (const auto& [name, bytes] : payloads)
    pl.push_back({{"name", name}, {"file", std::string(name) + ".bin"}, {"bytes", bytes->size()}});
  const std::array<float, 3> bg = job.background.value_or(model->background.value_or(std::array<float, 3>{0.f, 0.f, 0.f}));
  json header = {
      {"format", "s2r.web"},
      {"version", 1},
      {"facets", model->facets.size()},
      {"voxel_size_m", model->voxel_size_m},
      {"bounds", {{"min", vec3(model->bounds.min())}, {"max", vec3(model->bounds.max())}}},
      {"up", {0, 0, 1}},
      {"background", {bg[0], bg[1], bg[2]}},
      {"texture_width", W},
      {"texture_height", H},
      {"layers", layers},
      {"draw", {{"cameras", so.cameras}, {"min_weight", so.min_weight}, {"backface_cos", so.backface_cos},
                {"billboard_scale", d.billboard_scale}, {"clip_scale", d.clip_scale}, {"pixel_error", d.pixel_error},
                {"refine_steps", d.refine_steps}, {"depth_clip", d.depth_clip}, {"clip_fuzzy", d.clip_fuzzy}}},
      {"cameras", cams},
      {"payloads", pl}};

  double total = 0;
  for (const auto& [name, bytes] : payloads) {
    rep.counts[std::string("bytes_") + name] = static_cast<double>(bytes->size());
    total += static_cast<double>(bytes->size());
  }
  rep.counts["bytes"] = total;
  rep.counts["facets"] = static_cast<double>(model->facets.size());
  rep.counts["cameras"] = layers;
  rep.skipped["cameras_without_image"] = static_cast<double>(n - size_t(layers));
  auto written = write_folder_atomic(job.out, [&](const fs::path& tmp) -> Status {
    if (auto st = write_file_atomic(tmp / "index.html", web_index_html()); !st) return st;
    if (auto st = write_file_atomic(tmp / "viewer.js", web_viewer_js()); !st) return st;
    for (const auto& [name, bytes] : payloads)
      if (auto st = write_file_atomic(tmp / (std::string(name) + ".bin"), *bytes); !st) return st;
    if (auto st = write_file_atomic(tmp / "model.json", header.dump(1) + "\n"); !st) return st;
    rep.seconds = sw.seconds();
    return rep.write(tmp / "report.json");
  });
  if (!written) return std::unexpected(written.error());
  return rep;
}

}  // namespace s2r
