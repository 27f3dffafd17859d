// glTF 2.0 binary export with a baked texture atlas (reconstruct/gltf_export.h).
#include "reconstruct/gltf_export.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <optional>

#include <nlohmann/json.hpp>

#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/mesh.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "reconstruct/model.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

// World (z up) -> glTF (y up).
Eigen::Vector3d to_gltf(const Eigen::Vector3d& p) { return {p.x(), p.z(), -p.y()}; }
Eigen::Matrix3d gltf_from_world_rotation() {
  Eigen::Matrix3d r;
  r << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  return r;
}

struct Cam {
  Intrinsics K;
  Eigen::Isometry3d camera_from_world;
  Eigen::Vector3d centre;
  RgbazImage image;
};

// Bilinear RGB of an 8-bit RGBA image at a pixel position (centres at integers).
Eigen::Vector3d sample_rgb(const ImageU8& im, double x, double y) {
  const int x0 = std::clamp(static_cast<int>(std::floor(x)), 0, im.width - 1);
  const int y0 = std::clamp(static_cast<int>(std::floor(y)), 0, im.height - 1);
  const int x1 = std::min(x0 + 1, im.width - 1), y1 = std::min(y0 + 1, im.height - 1);
  const double fx = std::clamp(x - x0, 0.0, 1.0), fy = std::clamp(y - y0, 0.0, 1.0);
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (int ch = 0; ch < 3; ++ch) {
    const double top = im.at(x0, y0, ch) * (1 - fx) + im.at(x1, y0, ch) * fx;
    const double bot = im.at(x0, y1, ch) * (1 - fx) + im.at(x1, y1, ch) * fx;
    c[ch] = top * (1 - fy) + bot * fy;
  }
  return c;
}

void append(std::string& bin, const void* data, size_t bytes) {
  bin.append(static_cast<const char*>(data), bytes);
  while (bin.size() % 4) bin.push_back('\0');
}

}  // namespace

Result<Report> export_gltf(const GltfExportJob& job) {
  Stopwatch sw;
  Report rep;
  rep.stage = "export";
  rep.params["format"] = std::string("gltf");
  rep.params["mesh"] = job.mesh;
  if (job.mesh != "patch" && job.mesh != "surface") return fail(ErrorCode::invalid, "mesh: '" + job.mesh + "' (patch or surface)");
  if (job.atlas_max < 64 || job.atlas_max > 16384) return fail(ErrorCode::invalid, "atlas_max: must be 64..16384");
  if (job.max_cell < 4) return fail(ErrorCode::invalid, "max_cell: must be >= 4");
  if (job.out.extension() != ".glb") return fail(ErrorCode::invalid, "out: '" + job.out.string() + "' must end in .glb");
  auto model = load_model(job.model);
  if (!model) return fail_with_context(model.error(), "model");
  const std::optional<std::string>& rel = job.mesh == "patch" ? model->patch_mesh : model->surface_mesh;
  if (!rel)
    return fail(ErrorCode::not_found, "model '" + job.model.string() + "' has no " +
                                          (job.mesh == "patch" ? "patch mesh" : "fused surface") +
                                          " (a model of splats alone, or one written before meshes were kept): nothing to export as glTF");
  auto mesh = read_ply_mesh(job.model / *rel);
  if (!mesh) return fail_with_context(mesh.error(), "mesh");

  std::vector<Cam> cams;
  {
    Progress progress("export gltf: cameras", model->cameras.size());
    for (const auto& c : model->cameras) {
      progress.tick();
      if (c.texture.empty()) continue;
      auto im = read_rgbaz(job.model / c.texture);
      if (!im) return fail_with_context(im.error(), "camera texture");
      cams.push_back({c.intrinsics, c.world_from_camera.inverse(), c.world_from_camera.translation(), std::move(*im)});
    }
  }
  if (cams.empty())
    return fail(ErrorCode::not_found, "model '" + job.model.string() +
                                          "' has no camera images to bake a texture from (reconstructed with --no-textures)");

  // Triangles with area.
  std::vector<Eigen::Vector3i> tris;
  for (const auto& f : mesh->faces) {
    const Eigen::Vector3d a = mesh->vertices[f[0]].cast<double>(), b = mesh->vertices[f[1]].cast<double>(),
                          c = mesh->vertices[f[2]].cast<double>();
    if ((b - a).cross(c - a).norm() > 1e-14) tris.push_back(f);
    else rep.skipped["degenerate_triangles"] += 1;
  }
  if (tris.empty()) return fail(ErrorCode::invalid, "mesh: no triangle with area");
  const int T = static_cast<int>(tris.size());
  const int cols = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(T))));
  const int rows = (T + cols - 1) / cols;
  int cell = std::min(job.max_cell, job.atlas_max / std::max(cols, rows));
  // The largest cell whose power-of-two atlas stays within atlas_max.
  while (cell > 4 && (std::bit_ceil(static_cast<unsigned>(cols * cell)) > static_cast<unsigned>(job.atlas_max) ||
                      std::bit_ceil(static_cast<unsigned>(rows * cell)) > static_cast<unsigned>(job.atlas_max)))
    --cell;
  if (cell < 4)
    return fail(ErrorCode::invalid, "atlas_max: " + std::to_string(T) + " triangles need cells of 4 texels at least: an atlas of " +
                                        std::to_string(4 * cols) + " texels");
  // Power-of-two sides (mipmaps everywhere, WebGL 1 included); the cells fill the top-left.
  auto pot = [](int v) {
    int p = 1;
    while (p < v) p *= 2;
    return p;
  };
  const int W = pot(cols * cell), H = pot(rows * cell);
  ImageU8 atlas(W, H, 3, 0);
  const double w = model->voxel_size_m;
  std::atomic<int64_t> unseen{0};
  std::vector<Eigen::Vector2f> uv(3 * T);
  {
    Progress progress("export gltf: bake", T);
    constexpr int kChunk = 4096;
    for (int first = 0; first < T; first += kChunk) {
    const int count = std::min(kChunk, T - first);
    parallel_for(count, job.threads, [&](int i) {
      const int t = first + i;
      const Eigen::Vector3i& f = tris[t];
      const Eigen::Vector3d P[3] = {mesh->vertices[f[0]].cast<double>(), mesh->vertices[f[1]].cast<double>(),
                                    mesh->vertices[f[2]].cast<double>()};
      const Eigen::Vector3d n = (P[1] - P[0]).cross(P[2] - P[0]).normalized();
      const Eigen::Vector3d centroid = (P[0] + P[1] + P[2]) / 3;
      // Cameras by how head-on they see the triangle (either side: the
      // distance test decides which side a camera sees).
      std::vector<std::pair<double, int>> order;
      for (size_t k = 0; k < cams.size(); ++k) {
        const double cosang = std::abs(n.dot((cams[k].centre - centroid).normalized()));
        if (cosang > 0.1) order.push_back({cosang, static_cast<int>(k)});
      }
      std::sort(order.begin(), order.end(), std::greater<>());
      if (order.size() > 8) order.resize(8);
      // Cell corners (texel units): A (1, 1), B (cell - 2, 1), C (1, cell - 2).
      const int ox = (t % cols) * cell, oy = (t / cols) * cell;
      const Eigen::Vector2d A(ox + 1.0, oy + 1.0), B(ox + cell - 2.0, oy + 1.0), C(ox + 1.0, oy + cell - 2.0);
      const Eigen::Vector2d* corners[3] = {&A, &B, &C};
      for (int k = 0; k < 3; ++k) uv[3 * t + k] = Eigen::Vector2f(static_cast<float>(corners[k]->x() / W),
                                                                  static_cast<float>(corners[k]->y() / H));
      const double area = (B - A).x() * (C - A).y();
      for (int y = oy; y < oy + cell; ++y)
        for (int x = ox; x < ox + cell; ++x) {
          // Barycentric of the texel centre, clamped into the triangle.
          const Eigen::Vector2d q(x + 0.5, y + 0.5);
          double l1 = std::max(0.0, (q.x() - A.x()) * (C - A).y() / area);
          double l2 = std::max(0.0, (q.y() - A.y()) * (B - A).x() / area);
          if (l1 + l2 > 1) {
            const double s = l1 + l2;
            l1 /= s;
            l2 /= s;
          }
          const Eigen::Vector3d p = P[0] * (1 - l1 - l2) + P[1] * l1 + P[2] * l2;
          Eigen::Vector3d sum = Eigen::Vector3d::Zero();
          double weight = 0;
          int used = 0;
          for (const auto& [cosang, k] : order) {
            const Cam& c = cams[k];
            const Eigen::Vector3d pc = c.camera_from_world * p;
            if (pc.z() <= 0) continue;
            auto px = c.K.project(pc);
            if (!px || px->x() < 0 || px->y() < 0 || px->x() > c.K.width - 1 || px->y() > c.K.height - 1) continue;
            const int u = static_cast<int>(std::lround(px->x())), v = static_cast<int>(std::lround(px->y()));
            const float dist = c.image.distance.at(u, v);
            if (dist <= 0 || std::abs(dist - pc.norm()) > std::max(1.5 * w, 0.01 * pc.norm())) continue;
            const double wt = std::pow(cosang, 4);
            sum += wt * sample_rgb(c.image.rgba, px->x(), px->y());
            weight += wt;
            if (++used == 3) break;
          }
          if (weight == 0) {
            ++unseen;
            // No camera sees it: the most head-on camera's colour, unchecked.
            for (const auto& [cosang, k] : order) {
              auto px = cams[k].K.project(cams[k].camera_from_world * p);
              if (!px) continue;
              sum = sample_rgb(cams[k].image.rgba, px->x(), px->y());
              weight = 1;
              break;
            }
          }
          if (weight == 0) continue;
          for (int ch = 0; ch < 3; ++ch)
            atlas.at(x, y, ch) = static_cast<uint8_t>(std::clamp(std::lround(sum[ch] / weight), 0l, 255l));
        }
    });
    progress.tick(count);
    }
  }
  rep.skipped["texels_seen_by_no_camera"] = static_cast<double>(unseen.load());

  // The atlas as PNG bytes.
  const fs::path png = job.out.parent_path() / ("." + job.out.filename().string() + ".atlas-" + std::to_string(getpid()) + ".png");
  if (auto st = write_image(png, atlas); !st) return std::unexpected(st.error());
  auto png_bytes = read_file(png);
  std::error_code ec;
  fs::remove(png, ec);
  if (!png_bytes) return std::unexpected(png_bytes.error());

  // Buffers: positions, texcoords, indices, image.
  std::vector<float> pos(9 * T);
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(INFINITY), hi = Eigen::Vector3f::Constant(-INFINITY);
  for (int t = 0; t < T; ++t)
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3f g = to_gltf(mesh->vertices[tris[t][k]].cast<double>()).cast<float>();
      for (int a = 0; a < 3; ++a) pos[9 * t + 3 * k + a] = g[a];
      lo = lo.cwiseMin(g);
      hi = hi.cwiseMax(g);
    }
  std::vector<uint32_t> idx(3 * T);
  for (int i = 0; i < 3 * T; ++i) idx[i] = static_cast<uint32_t>(i);
  std::string bin;
  const size_t pos_off = bin.size();
  append(bin, pos.data(), pos.size() * 4);
  const size_t uv_off = bin.size();
  append(bin, uv.data(), uv.size() * 8);
  const size_t idx_off = bin.size();
  append(bin, idx.data(), idx.size() * 4);
  const size_t img_off = bin.size();
  append(bin, png_bytes->data(), png_bytes->size());

  json g;
  g["asset"] = {{"version", "2.0"}, {"generator", "scan2render s2r export gltf"}};
  g["extensionsUsed"] = {"KHR_materials_unlit"};
  g["buffers"] = {{{"byteLength", bin.size()}}};
  g["bufferViews"] = {
      {{"buffer", 0}, {"byteOffset", pos_off}, {"byteLength", pos.size() * 4}, {"target", 34962}},
      {{"buffer", 0}, {"byteOffset", uv_off}, {"byteLength", uv.size() * 8}, {"target", 34962}},
      {{"buffer", 0}, {"byteOffset", idx_off}, {"byteLength", idx.size() * 4}, {"target", 34963}},
      {{"buffer", 0}, {"byteOffset", img_off}, {"byteLength", png_bytes->size()}}};
  g["accessors"] = {
      {{"bufferView", 0}, {"componentType", 5126}, {"count", 3 * T}, {"type", "VEC3"},
       {"min", {lo.x(), lo.y(), lo.z()}}, {"max", {hi.x(), hi.y(), hi.z()}}},
      {{"bufferView", 1}, {"componentType", 5126}, {"count", 3 * T}, {"type", "VEC2"}},
      {{"bufferView", 2}, {"componentType", 5125}, {"count", 3 * T}, {"type", "SCALAR"}}};
  g["images"] = {{{"bufferView", 3}, {"mimeType", "image/png"}, {"name", "atlas"}}};
  g["samplers"] = {{{"magFilter", 9729}, {"minFilter", 9729}, {"wrapS", 33071}, {"wrapT", 33071}}};
  g["textures"] = {{{"source", 0}, {"sampler", 0}}};
  g["materials"] = {{{"name", "photos"},
                     {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0.0}, {"roughnessFactor", 1.0}}},
                     {"doubleSided", true},
                     {"extensions", {{"KHR_materials_unlit", json::object()}}}}};
  g["meshes"] = {{{"name", "surface"},
                  {"primitives", {{{"attributes", {{"POSITION", 0}, {"TEXCOORD_0", 1}}}, {"indices", 2}, {"material", 0}}}}}};
  json nodes = json::array();
  nodes.push_back({{"name", "surface"}, {"mesh", 0}});
  json cameras = json::array();
  const Eigen::Matrix3d rg = gltf_from_world_rotation();
  Eigen::Matrix3d cv_to_gl = Eigen::Matrix3d::Identity();
  cv_to_gl(1, 1) = -1;
  cv_to_gl(2, 2) = -1;
  for (size_t k = 0; k < model->cameras.size(); ++k) {
    const ModelCamera& c = model->cameras[k];
    const double znear = std::max(1e-3, 0.01 * model->bounds.diagonal().norm());
    cameras.push_back({{"type", "perspective"},
                       {"perspective", {{"yfov", 2 * std::atan(0.5 * c.intrinsics.height / c.intrinsics.fy)},
                                        {"aspectRatio", static_cast<double>(c.intrinsics.width) / c.intrinsics.height},
                                        {"znear", znear}}}});
    Eigen::Quaterniond q(rg * c.world_from_camera.rotation() * cv_to_gl);
    q.normalize();
    const Eigen::Vector3d tr = to_gltf(c.world_from_camera.translation());
    char name[32];
    std::snprintf(name, sizeof name, "camera_%04d", c.session_frame);
    nodes.push_back({{"name", name}, {"camera", k}, {"rotation", {q.x(), q.y(), q.z(), q.w()}},
                     {"translation", {tr.x(), tr.y(), tr.z()}}});
  }
  if (!cameras.empty()) g["cameras"] = cameras;
  json scene_nodes = json::array();
  for (size_t i = 0; i < nodes.size(); ++i) scene_nodes.push_back(i);
  g["nodes"] = nodes;
  g["scenes"] = {{{"nodes", scene_nodes}}};
  g["scene"] = 0;

  std::string text = g.dump();
  while (text.size() % 4) text.push_back(' ');
  std::string glb;
  auto u32 = [&](uint32_t v) { glb.append(reinterpret_cast<const char*>(&v), 4); };
  u32(0x46546C67);  // "glTF"
  u32(2);
  u32(static_cast<uint32_t>(12 + 8 + text.size() + 8 + bin.size()));
  u32(static_cast<uint32_t>(text.size()));
  u32(0x4E4F534A);  // "JSON"
  glb += text;
  u32(static_cast<uint32_t>(bin.size()));
  u32(0x004E4942);  // "BIN\0"
  glb += bin;
  if (auto st = write_file_atomic(job.out, glb); !st) return std::unexpected(st.error());

  rep.counts["triangles"] = T;
  rep.counts["cameras"] = static_cast<double>(model->cameras.size());
  rep.counts["atlas_width"] = W;
  rep.counts["atlas_height"] = H;
  rep.counts["cell_texels"] = cell;
  rep.counts["texels"] = static_cast<double>(T) * cell * cell;
  rep.counts["bytes"] = static_cast<double>(glb.size());
  rep.counts["atlas_png_bytes"] = static_cast<double>(png_bytes->size());
  rep.seconds = sw.seconds();
  return rep;
}

}  // namespace s2r
