#include "render/facet_selection.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/parallel.h"
#include "core/report.h"

namespace s2r {

int blend_weights(const double* a, int count, int k, float* weights) {
  if (count <= 0 || k <= 0) return 0;
  k = std::min(k, kMaxBlendCameras);
  if (a[0] < 1e-6) {  // the view is this camera's: its texel is exact
    weights[0] = 1.f;
    return 1;
  }
  const int used = std::min(k, count);
  // Beyond the best k the next camera's angle is the threshold; with no
  // camera beyond, no ranking can change and the weights only need to stay
  // finite and smooth.
  const double threshold = count > k ? a[k] : std::numbers::pi;
  double w[kMaxBlendCameras], sum = 0;
  for (int i = 0; i < used; ++i) {
    w[i] = std::max(0.0, 1.0 - a[i] / threshold) / a[i];
    sum += w[i];
  }
  if (!(sum > 0)) {  // every used camera ties with the threshold
    weights[0] = 1.f;
    return 1;
  }
  for (int i = 0; i < used; ++i) weights[i] = static_cast<float>(w[i] / sum);
  return used;
}

int prune_weights(float* w, int used, double min_weight) {
  if (used <= 1 || !(min_weight > 0)) return used;
  int kept = 1;
  float sum = w[0];
  for (int i = 1; i < used; ++i)
    if (w[i] >= min_weight) {
      w[kept++] = w[i];
      sum += w[i];
    }
  for (int i = 0; i < kept; ++i) w[i] /= sum;
  for (int i = kept; i < used; ++i) w[i] = 0.f;
  return kept;
}

bool sphere_outside_view(const Eigen::Isometry3d& camera_from_world, const Intrinsics& K, const Eigen::Vector3d& c,
                         double radius, double near_m) {
  const Eigen::Vector3d p = camera_from_world * c;
  if (p.z() + radius <= near_m) return true;
  if (p.z() <= radius) return false;  // the sphere contains the eye plane: keep
  // The lens moves points by a few per cent of the image; the test uses the
  // pinhole part with that much margin.
  const double margin_x = 0.1 * K.width, margin_y = 0.1 * K.height;
  const double z = p.z() - radius;  // nearest depth: the largest footprint
  const double u = K.fx * p.x() / p.z() + K.cx, v = K.fy * p.y() / p.z() + K.cy;
  const double ru = K.fx * radius / z + margin_x, rv = K.fy * radius / z + margin_y;
  return u + ru < -0.5 || v + rv < -0.5 || u - ru > K.width - 0.5 || v - rv > K.height - 0.5;
}

SelectionStats select_facets(const FacetSet& set, const std::vector<ModelCamera>& cameras, const ViewCamera& view,
                             const SelectionOptions& o, std::vector<FacetInstance>& out) {
  Stopwatch clock;
  SelectionStats total;
  const std::vector<FacetRecord>& facets = set.facets;
  const size_t count = set.candidates ? set.candidates->size() : facets.size();
  total.facets = count;
  out.clear();
  const int k = std::clamp(o.cameras, 1, kMaxBlendCameras);
  const Eigen::Isometry3d camera_from_world = view.world_from_camera.inverse();
  const Eigen::Vector3d eye = view.eye();
  std::vector<Eigen::Vector3d> centres;
  for (const auto& c : cameras) centres.push_back(c.world_from_camera.translation());

  constexpr int kChunk = 4096;
  const int chunks = static_cast<int>((count + kChunk - 1) / kChunk);
  std::vector<std::vector<FacetInstance>> parts(static_cast<size_t>(chunks));
  std::vector<SelectionStats> stats(static_cast<size_t>(chunks));
  parallel_for(chunks, o.threads, [&](int chunk) {
    auto& part = parts[size_t(chunk)];
    auto& st = stats[size_t(chunk)];
    std::vector<std::pair<double, int>> cams;
    double angles[kMaxBlendCameras + 1];
    const size_t end = std::min(count, size_t(chunk + 1) * kChunk);
    for (size_t s = size_t(chunk) * kChunk; s < end; ++s) {
      const size_t i = set.candidates ? (*set.candidates)[s] : s;
      const FacetRecord& f = facets[i];
      const Eigen::Vector3d c(f.center[0], f.center[1], f.center[2]);
      if (o.frustum_cull && sphere_outside_view(camera_from_world, view.K, c, 0.5 * std::sqrt(3.0) * f.size, o.near_m)) {
        ++st.outside_frustum;
        continue;
      }
      Eigen::Vector3d to_eye = eye - c;
      const double dist = to_eye.norm();
      if (dist > 0) to_eye /= dist;
      const Eigen::Vector3d n(f.normal[0], f.normal[1], f.normal[2]);
      if (o.backface_cull && n.squaredNorm() > 0.25 && n.dot(to_eye) < o.backface_cos * n.norm()) {
        ++st.back_facing;
        continue;
      }
      if (f.camera_count == 0) {
        ++st.no_camera;
        continue;
      }
      cams.clear();
      for (uint32_t j = 0; j < f.camera_count; ++j) {
        const uint32_t ci = set.facet_cameras[f.first_camera + j];
        const Eigen::Vector3d to_cam = (centres[ci] - c).normalized();
        const double angle = angle_between(to_cam, to_eye);
        cams.emplace_back(angle, int(ci));
      }
      const int keep = std::min<int>(k + 1, int(cams.size()));
      std::partial_sort(cams.begin(), cams.begin() + keep, cams.end());
      for (int j = 0; j < keep; ++j) angles[j] = cams[size_t(j)].first;
      FacetInstance inst;
      inst.facet = static_cast<uint32_t>(i);
      float w[kMaxBlendCameras] = {};
      const int blended = blend_weights(angles, int(cams.size()), k, w);
      const int used = prune_weights(w, blended, o.min_weight);
      st.cameras_pruned += size_t(blended - used);
      for (int j = 0; j < kMaxBlendCameras; ++j) {
        inst.camera[j] = j < used ? cams[size_t(j)].second : -1;
        inst.weight[j] = j < used ? w[j] : 0.f;
      }
      if (blended == 1 && cams.size() > 1) ++st.exact_camera;
      if (cams.size() == 1) ++st.single_camera;
      part.push_back(inst);
    }
  });
  for (int c = 0; c < chunks; ++c) {
    out.insert(out.end(), parts[size_t(c)].begin(), parts[size_t(c)].end());
    const auto& st = stats[size_t(c)];
    total.outside_frustum += st.outside_frustum;
    total.back_facing += st.back_facing;
    total.no_camera += st.no_camera;
    total.exact_camera += st.exact_camera;
    total.single_camera += st.single_camera;
    total.cameras_pruned += st.cameras_pruned;
  }
  if (o.front_to_back) {
    std::vector<std::pair<float, uint32_t>> order(out.size());
    for (size_t i = 0; i < out.size(); ++i) {
      const float* c = facets[out[i].facet].center;
      order[i] = {float((Eigen::Vector3d(c[0], c[1], c[2]) - eye).squaredNorm()), uint32_t(i)};
    }
    std::sort(order.begin(), order.end());
    std::vector<FacetInstance> sorted(out.size());
    for (size_t i = 0; i < out.size(); ++i) sorted[i] = out[order[i].second];
    out.swap(sorted);
  }
  total.drawn = out.size();
  total.seconds = clock.seconds();
  return total;
}

}  // namespace s2r
