#include "reconstruct/rig_eval.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "capture/ground_truth.h"
#include "core/image_io.h"
#include "reconstruct/microfacets.h"
#include "reconstruct/view_cloud.h"

#include <numbers>
#include <unordered_map>

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

SurfaceDistance::SurfaceDistance(const Mesh& truth, double sample_m)
    : index_(std::make_unique<NeighbourIndex>(sample_surface(truth, sample_m))) {}
SurfaceDistance::~SurfaceDistance() = default;

SurfaceError SurfaceDistance::error(const std::vector<FacetRecord>& facets) const {
  SurfaceError e;
  e.facets = facets.size();
  if (facets.empty()) return e;
  std::vector<double> d(facets.size());
  size_t within = 0;
  for (size_t i = 0; i < facets.size(); ++i) {
    const Eigen::Vector3f c(facets[i].center[0], facets[i].center[1], facets[i].center[2]);
    float d2 = 0;
    const int k = index_->nearest(c, 1e3f, &d2);
    d[i] = k < 0 ? std::numeric_limits<double>::infinity() : std::sqrt(double(d2));
    within += d[i] <= facets[i].size;
  }
  e.within_size = double(within) / double(facets.size());
  e.median_m = quantile(d, 0.5);
  e.p99_m = quantile(d, 0.99);
  e.max_m = *std::max_element(d.begin(), d.end());
  return e;
}

SurfaceError facet_surface_error(const std::vector<FacetRecord>& facets, const Mesh& truth, double sample_m) {
  if (facets.empty()) return {};
  return SurfaceDistance(truth, sample_m).error(facets);
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
  auto truth = load_ground_truth(session_dir);
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

Result<TexelError> measure_texel_error(const Model& model, const fs::path& session_dir, double angle_deg, int stride) {
  TexelError te;
  te.angle_deg = angle_deg;
  if (model.cameras.size() < 2 || model.facets.empty()) return fail("texel error: needs two cameras and facets");
  std::vector<Eigen::Isometry3d> poses;
  for (const auto& c : model.cameras) poses.push_back(c.world_from_camera);
  const Eigen::Vector3d centre = optical_axes_centre(poses);
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < poses.size(); ++i)
    axis += (poses[i].translation() - centre).cross(poses[(i + 1) % poses.size()].translation() - centre);
  if (axis.norm() < 1e-12) return fail("texel error: the cameras do not circle the object");
  axis.normalize();
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle_deg * std::numbers::pi / 180, axis).toRotationMatrix();
  // Facets in a hash grid of the largest facet size.
  float cell = 0;
  for (const auto& f : model.facets) cell = std::max(cell, f.size);
  auto key = [&](const Eigen::Vector3f& p) {
    const Eigen::Vector3i k = (p / cell).array().floor().cast<int>();
    return (uint64_t(uint32_t(k.x()) & 0x1fffff) << 42) | (uint64_t(uint32_t(k.y()) & 0x1fffff) << 21) | uint64_t(uint32_t(k.z()) & 0x1fffff);
  };
  std::unordered_map<uint64_t, std::vector<uint32_t>> grid;
  for (uint32_t i = 0; i < model.facets.size(); ++i) {
    const auto& f = model.facets[i];
    grid[key(Eigen::Vector3f(f.center[0], f.center[1], f.center[2]))].push_back(i);
  }
  std::vector<double> err;
  for (const auto& cam : model.cameras) {
    auto gt = read_image_float(session_dir / "ground_truth" / "depth_color" / frame_file_name(cam.session_frame, "exr"));
    if (!gt) return std::unexpected(gt.error());
    const Eigen::Vector3d eye = cam.world_from_camera.translation();
    const Eigen::Vector3d view_eye = centre + R * (eye - centre);
    const double f = cam.intrinsics.fx;
    for (int y = 0; y < gt->height; y += stride)
      for (int x = 0; x < gt->width; x += stride) {
        const float z = gt->at(x, y);
        if (!(z > 0)) continue;
        auto r = cam.intrinsics.ray({double(x), double(y)});
        if (!r) continue;
        const Eigen::Vector3d P = cam.world_from_camera * (*r * z);
        const Eigen::Vector3d u = (P - eye).normalized();
        const Eigen::Vector3d v = (P - view_eye).normalized();
        const double zv = (P - view_eye).norm();
        // In-plane axes of billboards facing the view.
        const Eigen::Vector3d bx = v.unitOrthogonal(), by = v.cross(bx);
        double worst = -1, worst_ratio = 0;
        const Eigen::Vector3i k0 = (P.cast<float>() / cell).array().floor().cast<int>();
        for (int dx = -1; dx <= 1; ++dx)
          for (int dy = -1; dy <= 1; ++dy)
            for (int dz = -1; dz <= 1; ++dz) {
              const Eigen::Vector3f q = ((k0 + Eigen::Vector3i(dx, dy, dz)).cast<float>() + Eigen::Vector3f::Constant(0.5f)) * cell;
              auto it = grid.find(key(q));
              if (it == grid.end()) continue;
              for (uint32_t fi : it->second) {
                const auto& F = model.facets[fi];
                const Eigen::Vector3d C(F.center[0], F.center[1], F.center[2]);
                const double t = (C - P).dot(v) / u.dot(v);
                if (std::abs(t) >= 0.5 * F.size) continue;  // depth clip
                const Eigen::Vector3d Q = P + t * u;
                const double half = 0.5 * std::sqrt(3.0) * F.size;
                if (std::abs((Q - C).dot(bx)) > half || std::abs((Q - C).dot(by)) > half) continue;  // off the billboard
                const Eigen::Vector3d d = Q - P;
                const double e_px = f * (d - d.dot(v) * v).norm() / zv;
                worst = std::max(worst, e_px);
                // The bound at this texel: alpha is the angle between its camera ray and the view ray here.
                const double s_here = u.cross(v).norm();
                if (s_here > 1e-9) worst_ratio = std::max(worst_ratio, e_px / (f * 0.5 * F.size * s_here / zv));
              }
            }
        if (worst < 0) continue;
        err.push_back(worst);
        te.max_ratio = std::max(te.max_ratio, worst_ratio);
      }
  }
  te.texels = err.size();
  te.median_px = quantile(err, 0.5);
  te.p99_px = quantile(err, 0.99);
  te.max_px = err.empty() ? 0 : *std::max_element(err.begin(), err.end());
  return te;
}

}  // namespace s2r
