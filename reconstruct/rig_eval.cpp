#include "reconstruct/rig_eval.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "capture/synth_rig.h"
#include "core/image_io.h"
#include "reconstruct/view_cloud.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, size_t(q * double(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + long(k), v.end());
  return v[k];
}

std::vector<Eigen::Vector3f> sample_surface(const Mesh& mesh, double spacing) {
  std::mt19937 rng(12345);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<Eigen::Vector3f> out;
  for (const auto& f : mesh.faces) {
    const Eigen::Vector3f a = mesh.vertices[size_t(f[0])], b = mesh.vertices[size_t(f[1])], c = mesh.vertices[size_t(f[2])];
    const double area = 0.5 * (b - a).cross(c - a).norm();
    const int n = 1 + int(2 * area / (spacing * spacing));
    out.push_back((a + b + c) / 3.f);
    for (int i = 1; i < n; ++i) {
      float s = u(rng), t = u(rng);
      if (s + t > 1) s = 1 - s, t = 1 - t;
      out.push_back(a + s * (b - a) + t * (c - a));
    }
  }
  return out;
}

}  // namespace

SurfaceError facet_surface_error(const std::vector<FacetRecord>& facets, const Mesh& truth, double sample_m) {
  SurfaceError e;
  e.facets = facets.size();
  if (facets.empty()) return e;
  const NeighbourIndex index(sample_surface(truth, sample_m));
  std::vector<double> d(facets.size());
  size_t within = 0;
  for (size_t i = 0; i < facets.size(); ++i) {
    const Eigen::Vector3f c(facets[i].center[0], facets[i].center[1], facets[i].center[2]);
    float d2 = 0;
    const int k = index.nearest(c, 1e3f, &d2);
    d[i] = k < 0 ? std::numeric_limits<double>::infinity() : std::sqrt(double(d2));
    within += d[i] <= facets[i].size;
  }
  e.within_size = double(within) / double(facets.size());
  e.median_m = quantile(d, 0.5);
  e.p99_m = quantile(d, 0.99);
  e.max_m = *std::max_element(d.begin(), d.end());
  return e;
}

Result<DepthError> camera_depth_error(const Model& model, const fs::path& model_dir, const fs::path& session_dir) {
  DepthError e;
  std::vector<double> err;
  size_t truly = 0, missing = 0;
  for (const auto& cam : model.cameras) {
    if (cam.texture.empty()) continue;
    auto tex = read_rgbaz(model_dir / cam.texture);
    if (!tex) return std::unexpected(tex.error());
    auto gt = read_image_float(session_dir / "ground_truth" / "depth_color" / frame_file_name(cam.session_frame, "exr"));
    if (!gt) return std::unexpected(gt.error());
    if (gt->width != tex->distance.width || gt->height != tex->distance.height)
      return fail("ground truth depth and camera texture differ in size");
    for (int y = 0; y < gt->height; ++y)
      for (int x = 0; x < gt->width; ++x) {
        const float z = gt->at(x, y);
        if (!(z > 0)) continue;
        ++truly;
        const float d = tex->distance.at(x, y);
        if (!(d > 0)) {
          ++missing;
          continue;
        }
        auto r = cam.intrinsics.ray({double(x), double(y)});
        if (!r) continue;
        err.push_back(std::abs(d - z * r->norm()));
      }
  }
  e.pixels = err.size();
  e.median_m = quantile(err, 0.5);
  e.p90_m = quantile(err, 0.9);
  e.missing = truly ? double(missing) / double(truly) : 0;
  return e;
}

Result<StrandCoverage> strand_coverage(const Model& model, const fs::path& session_dir) {
  auto truth = load_synth_truth(session_dir);
  if (!truth) return std::unexpected(truth.error());
  StrandCoverage sc;
  size_t covered = 0, all_covered = 0, over = 0;
  for (const auto& cam : model.cameras) {
    if (cam.session_frame < 0 || size_t(cam.session_frame) >= truth->world_from_camera.size()) continue;
    auto labels = read_image_u8(session_dir / "ground_truth" / "labels" / frame_file_name(cam.session_frame, "png"));
    if (!labels) return std::unexpected(labels.error());
    const Intrinsics& K = truth->depth;
    const Eigen::Isometry3d depth_from_world =
        (truth->world_from_camera[size_t(cam.session_frame)] * truth->color_from_depth).inverse();
    ImageU8 cover(labels->width, labels->height, 1, 0);
    for (const auto& f : model.facets) {
      const Eigen::Vector3d p = depth_from_world * Eigen::Vector3d(f.center[0], f.center[1], f.center[2]);
      auto px = K.project(p);
      if (!px) continue;
      const double half = 0.5 * std::sqrt(3.0) * f.size * K.fx / p.z();
      const int x0 = std::max(0, int(std::floor(px->x() - half + 0.5))), x1 = std::min(cover.width - 1, int(std::floor(px->x() + half + 0.5)));
      const int y0 = std::max(0, int(std::floor(px->y() - half + 0.5))), y1 = std::min(cover.height - 1, int(std::floor(px->y() + half + 0.5)));
      for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) cover.at(x, y) = 1;
    }
    for (size_t i = 0; i < cover.pixels(); ++i) {
      const uint8_t label = labels->data[i * size_t(labels->channels)];
      if (label == 2) {
        ++sc.strand_pixels;
        covered += cover.data[i];
      }
      all_covered += cover.data[i];
      over += cover.data[i] && label == 0;
    }
  }
  sc.covered = sc.strand_pixels ? double(covered) / double(sc.strand_pixels) : 0;
  sc.background = all_covered ? double(over) / double(all_covered) : 0;
  return sc;
}

}  // namespace s2r
