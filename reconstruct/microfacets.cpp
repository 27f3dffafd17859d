#include "reconstruct/microfacets.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <tuple>
#include <unordered_map>

#include <Eigen/Eigenvalues>
#include <spdlog/fmt/fmt.h>

#include "core/parallel.h"

namespace s2r {

double texel_error_bound(double w, double delta_rad) {
  return 0.5 * w * std::sin(std::clamp(delta_rad, 0.0, std::numbers::pi / 2));
}

double voxel_for_error(double target_px, double focal_px, double distance_m, double delta_rad) {
  // f (w/2) sin(delta) / z <= target  =>  w <= 2 target z / (f sin(delta)).
  const double s = std::sin(std::clamp(delta_rad, 1e-6, std::numbers::pi / 2));
  return 2 * target_px * distance_m / (focal_px * s);
}

VoxelChoice choose_voxel(const VoxelRequest& r) {
  VoxelChoice c;
  double w0;
  if (r.given_m) {
    w0 = *r.given_m;
  } else {
    // Densely spaced cameras allow large facets by the bound alone; a facet is
    // still kept within kMaxFacetPixels input pixels, beyond which it blurs
    // detail the photos hold and its clipping window (w/2) stops telling
    // surfaces apart.
    constexpr double kMaxFacetPixels = 8;
    c.automatic = true;
    double w_max = voxel_for_error(r.target_error_px, r.focal_px, r.near_distance_m, r.delta_rad);
    if (w_max > kMaxFacetPixels * r.pixel_m) {
      w_max = kMaxFacetPixels * r.pixel_m;
      c.limited_by_pixels = true;
    }
    c.bound_m = w_max;
    w0 = r.per_region ? w_max / 2 : w_max;
    if (w0 < 2 * r.pixel_m) {
      c.warnings.push_back(fmt::format("the error bound allows {:.2f} mm facets, under two input pixels ({:.2f} mm): "
                                       "using two pixels (cameras this close in angle need no finer facets)",
                                       1e3 * w0, 2e3 * r.pixel_m));
      w0 = 2 * r.pixel_m;
    }
    if (w0 > r.extent_m / 4) w0 = r.extent_m / 4;
  }
  if (w0 < r.pixel_m)
    c.warnings.push_back(fmt::format("voxel {:.3f} mm is below one input pixel at the viewing distance ({:.3f} mm): "
                                     "facets finer than the photos",
                                     1e3 * w0, 1e3 * r.pixel_m));
  c.base_m = w0;
  c.coarse_m = r.per_region ? 2 * w0 : w0;
  return c;
}

Intrinsics visibility_grid(const Intrinsics& K, int stride) {
  const int k = std::max(1, stride), off = (k - 1) / 2;
  if (k == 1) return K;
  Intrinsics G = K;
  G.width = K.width > off ? (K.width - 1 - off) / k + 1 : 0;
  G.height = K.height > off ? (K.height - 1 - off) / k + 1 : 0;
  G.fx = K.fx / k, G.fy = K.fy / k;
  G.cx = (K.cx - off) / k, G.cy = (K.cy - off) / k;
  return G;
}

int visibility_stride(double w, double far_m, const Intrinsics& K) {
  const double pixel_m = far_m / std::min(K.fx, K.fy);  // a pixel's width at far_m
  if (!(w > 0) || !(pixel_m > 0) || !std::isfinite(pixel_m)) return 1;
  // At most 64, and at most the image's smaller side (the grid keeps a pixel each way).
  const double widest = std::max(1, std::min({64, K.width, K.height}));
  return int(std::clamp(std::floor(w / (3 * pixel_m)), 1.0, widest));
}

CameraSpacing camera_spacing(const std::vector<Eigen::Isometry3d>& cams, const Eigen::Vector3d& centre) {
  CameraSpacing cs;
  if (cams.empty()) return cs;
  std::vector<Eigen::Vector3d> dirs;
  std::vector<double> dist, gaps;
  for (const auto& c : cams) {
    const Eigen::Vector3d d = c.translation() - centre;
    dist.push_back(d.norm());
    dirs.push_back(d.norm() > 0 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d::UnitZ());
  }
  for (size_t i = 0; i < dirs.size(); ++i) {
    double best = std::numbers::pi;  // a lone camera: any view may be opposite
    for (size_t j = 0; j < dirs.size(); ++j)
      if (i != j) best = std::min(best, angle_between(dirs[i], dirs[j]));
    gaps.push_back(best);
  }
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  cs.max_gap_rad = *std::max_element(gaps.begin(), gaps.end());
  cs.median_gap_rad = median(gaps);
  cs.median_distance_m = median(dist);
  return cs;
}

Eigen::Vector3d optical_axes_centre(const std::vector<Eigen::Isometry3d>& cams) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero(), mean_c = Eigen::Vector3d::Zero(), mean_d = Eigen::Vector3d::Zero();
  for (const auto& c : cams) {
    const Eigen::Vector3d o = c.translation(), d = c.linear().col(2).normalized();
    const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d * d.transpose();
    A += P;
    b += P * o;
    mean_c += o;
    mean_d += d;
  }
  if (cams.empty()) return Eigen::Vector3d::Zero();
  mean_c /= double(cams.size());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(A);
  if (es.eigenvalues()(0) > 1e-3 * es.eigenvalues()(2)) return A.ldlt().solve(b);
  return mean_c + mean_d.normalized();  // parallel axes: one metre ahead
}

FacetStats build_facets(const std::vector<EvidenceVoxel>& ev, const std::vector<FacetCamera>& cameras,
                        const FacetOptions& o, std::vector<FacetRecord>& facets, std::vector<uint32_t>& facet_cameras) {
  FacetStats st;
  st.evidence = ev.size();
  struct Draft {
    Eigen::Vector3f centre, normal;
    float size, reliability;
    bool fuzzy;
  };
  std::vector<Draft> drafts;
  drafts.reserve(ev.size());
  auto weak = [&](const EvidenceVoxel& e) { return e.fuzzy || e.reliability < o.reliable; };
  // Parents (2x2x2 voxels) with a reliable member keep their voxels fine.
  auto key = [](const Eigen::Vector3i& ijk) {
    const Eigen::Vector3i p(ijk.x() >> 1, ijk.y() >> 1, ijk.z() >> 1);
    return (uint64_t(uint32_t(p.x()) & 0x1fffff) << 42) | (uint64_t(uint32_t(p.y()) & 0x1fffff) << 21) |
           uint64_t(uint32_t(p.z()) & 0x1fffff);
  };
  std::unordered_map<uint64_t, bool> parent_reliable;
  if (o.per_region)
    for (const auto& e : ev) parent_reliable[key(e.ijk)] |= !weak(e);
  struct Merge {
    Eigen::Vector3f sum_c = Eigen::Vector3f::Zero(), sum_n = Eigen::Vector3f::Zero();
    float sum_r = 0;
    int n = 0;
    bool fuzzy = true;
  };
  std::unordered_map<uint64_t, Merge> merges;
  for (const auto& e : ev) {
    if (o.per_region && !parent_reliable[key(e.ijk)]) {
      Merge& m = merges[key(e.ijk)];
      m.sum_c += e.centre, m.sum_n += e.normal, m.sum_r += e.reliability, ++m.n;
      m.fuzzy = m.fuzzy && e.fuzzy;
      continue;
    }
    drafts.push_back({e.centre, e.normal, float(o.voxel_m), e.reliability, e.fuzzy});
  }
  for (const auto& [k, m] : merges) {
    const Eigen::Vector3f n = m.sum_n.norm() > 1e-6f ? Eigen::Vector3f(m.sum_n.normalized()) : Eigen::Vector3f::Zero();
    drafts.push_back({m.sum_c / float(m.n), n, float(2 * o.voxel_m), m.sum_r / float(m.n), m.fuzzy});
  }
  // Deterministic order (the hash map's is not): by position.
  std::sort(drafts.begin(), drafts.end(), [](const Draft& a, const Draft& b) {
    return std::tie(a.centre.x(), a.centre.y(), a.centre.z(), a.size) < std::tie(b.centre.x(), b.centre.y(), b.centre.z(), b.size);
  });

  // Visibility, in parallel over chunks of facets.
  struct CamXf {
    Eigen::Matrix3f R;
    Eigen::Vector3f t;
  };
  std::vector<CamXf> xf;
  for (const auto& c : cameras) {
    const Eigen::Isometry3d inv = c.world_from_camera.inverse();
    xf.push_back({inv.linear().cast<float>(), inv.translation().cast<float>()});
  }
  auto tolerance = [](const Draft& d) { return 0.5f * std::sqrt(3.f) * d.size; };
  // Camera by camera (in parallel): its depth, given or made for this test
  // and dropped after it, then every facet against it.
  std::vector<std::vector<uint32_t>> seen_by(cameras.size());
  std::vector<size_t> occluded(cameras.size(), 0), outside(cameras.size(), 0);
  parallel_for(int(cameras.size()), worker_count(o.threads), [&](int ci) {
    const size_t c = size_t(ci);
    const FacetCamera& cam = cameras[c];
    ImageF made;
    const ImageF* D = cam.distance;
    if (!D && cam.distance_at) made = cam.distance_at(), D = &made;
    const Intrinsics& K = cam.intrinsics;
    const int k = std::max(1, cam.stride), off = (k - 1) / 2;
    const Intrinsics G = visibility_grid(K, k);
    // Grid point (gx, gy) is D's pixel (gx, gy), or (k gx + off, k gy + off) in a whole image.
    const bool whole = D && D->width == K.width && D->height == K.height;
    if (D && !whole && (D->width != G.width || D->height != G.height)) D = nullptr;  // no usable depth: nothing occludes
    if (G.width < 1 || G.height < 1) D = nullptr;
    const int step = whole ? k : 1, start = whole ? off : 0;
    for (size_t i = 0; i < drafts.size(); ++i) {
      const Draft& d = drafts[i];
      const Eigen::Vector3f pc = xf[c].R * d.centre + xf[c].t;
      auto px = K.project(pc.cast<double>());
      if (!px || !K.contains(*px)) {
        ++outside[c];
        continue;
      }
      if (D) {
        const int gx = std::clamp(round_half_away((px->x() - off) / k), 0, G.width - 1);
        const int gy = std::clamp(round_half_away((px->y() - off) / k), 0, G.height - 1);
        const float dd = D->data[size_t(start + step * gy) * size_t(D->width) + size_t(start + step * gx)];
        if (dd > 0 && pc.norm() > dd + tolerance(d)) {
          ++occluded[c];
          continue;
        }
      }
      seen_by[c].push_back(uint32_t(i));
    }
  });
  // Each facet's cameras in ascending order.
  std::vector<uint32_t> count(drafts.size(), 0);
  for (size_t c = 0; c < cameras.size(); ++c) {
    st.occluded += occluded[c];
    st.outside_image += outside[c];
    for (uint32_t i : seen_by[c]) ++count[i];
  }
  std::vector<uint32_t> first(drafts.size(), 0);
  size_t links = 0;
  for (size_t i = 0; i < drafts.size(); ++i) first[i] = uint32_t(links), links += count[i];
  facet_cameras.assign(links, 0);
  {
    std::vector<uint32_t> fill = first;
    for (size_t c = 0; c < cameras.size(); ++c)
      for (uint32_t i : seen_by[c]) facet_cameras[fill[i]++] = uint32_t(c);
  }
  facets.clear();
  facets.reserve(drafts.size());
  for (size_t i = 0; i < drafts.size(); ++i) {
    const Draft& d = drafts[i];
    if (count[i] == 0) {
      ++st.unseen;
      if (!o.keep_unseen) continue;
    }
    FacetRecord r{};
    for (int k = 0; k < 3; ++k) r.center[k] = d.centre[k], r.normal[k] = d.normal[k];
    r.size = d.size;
    r.reliability = std::clamp(d.reliability, 0.f, 1.f);
    r.first_camera = first[i];
    r.camera_count = count[i];
    facets.push_back(r);
    st.fuzzy += d.fuzzy;
    (d.size > float(o.voxel_m) * 1.5f ? st.coarse : st.fine) += 1;
  }
  st.facets = facets.size();
  st.camera_links = facet_cameras.size();
  return st;
}

}  // namespace s2r
