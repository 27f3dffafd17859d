#include "render/facet_lod.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <Eigen/Geometry>

#include "core/report.h"
#include "render/facet_selection.h"
#include "trace/visual_field.h"

namespace s2r {

namespace {

constexpr double kPi = std::numbers::pi;
// The cones hold the normals at the surface crossings; a facet's own normal
// (the fused distance's gradient at its centre) can differ by a few degrees,
// so a node is culled only this far beyond the per-facet back-face angle.
constexpr double kConeMargin = 10 * kPi / 180;

Eigen::Vector3f vec(const float* p) { return {p[0], p[1], p[2]}; }

}  // namespace

struct FacetHierarchy::Frame {
  Eigen::Isometry3d camera_from_world;
  Eigen::Vector3d eye;
  const Intrinsics* K = nullptr;
  double focal_px = 1, near_m = 0.01;
  double back_angle = 0;  // a normal this far from the eye direction faces away
  LodOptions o;
  std::optional<EyeFrame> field;
};

FacetHierarchy FacetHierarchy::build(const Model& m, const std::vector<float>& lum) {
  FacetHierarchy h;
  h.model_facets_ = m.facets.size();
  h.facets_ = m.facets;
  h.facet_cameras_ = m.facet_cameras;
  for (const auto& f : m.facets) h.least_reliability_.push_back(f.reliability);
  for (const auto& c : m.cameras) h.camera_centres_.push_back(c.world_from_camera.translation().cast<float>());
  const size_t count = m.octree.size();
  if (count == 0 || !(m.voxel_size_m > 0)) {
    for (uint32_t i = 0; i < m.facets.size(); ++i) h.loose_.push_back(i);
    return h;
  }
  const double w0 = m.voxel_size_m;
  const int top = m.octree_max_level;
  auto cells = [&](const OctreeRecord& r) { return 1 << (top - r.level); };
  auto contains = [&](const OctreeRecord& r, const Eigen::Vector3i& c) {
    const int s = cells(r);
    for (int k = 0; k < 3; ++k)
      if (c[k] < r.origin[k] || c[k] >= r.origin[k] + s) return false;
    return true;
  };
  // Each facet to the deepest node whose cells contain its centre (cell i
  // spans the samples i..i+1, i.e. i w0 .. (i+1) w0).
  std::vector<std::vector<uint32_t>> own(count);
  for (uint32_t i = 0; i < m.facets.size(); ++i) {
    const float* c = m.facets[i].center;
    const Eigen::Vector3i cell(int(std::floor(c[0] / w0 + 1e-4)), int(std::floor(c[1] / w0 + 1e-4)),
                               int(std::floor(c[2] / w0 + 1e-4)));
    if (!contains(m.octree[0], cell)) {
      h.loose_.push_back(i);
      continue;
    }
    size_t n = 0;
    for (;;) {
      const OctreeRecord& r = m.octree[n];
      if (r.first_child == kNoChild) break;
      size_t next = n;
      for (uint32_t ch = 0; ch < r.children; ++ch)
        if (contains(m.octree[r.first_child + ch], cell)) next = r.first_child + ch;
      if (next == n) break;
      n = next;
    }
    own[n].push_back(i);
  }
  // Pre-order ranges (iterative: the loader checked the links).
  h.nodes_.resize(count);
  h.order_.reserve(m.facets.size());
  std::vector<std::pair<uint32_t, bool>> stack{{0u, false}};
  while (!stack.empty()) {
    auto [n, done] = stack.back();
    stack.pop_back();
    Node& node = h.nodes_[n];
    if (done) {
      node.end = uint32_t(h.order_.size());
      continue;
    }
    const OctreeRecord& r = m.octree[n];
    node.begin = uint32_t(h.order_.size());
    h.order_.insert(h.order_.end(), own[n].begin(), own[n].end());
    node.own_end = uint32_t(h.order_.size());
    stack.push_back({n, true});
    if (r.first_child != kNoChild) {
      node.first_child = int32_t(r.first_child);
      node.children = r.children;
      for (int ch = int(r.children) - 1; ch >= 0; --ch) stack.push_back({r.first_child + uint32_t(ch), false});
    }
  }
  // Per node: its billboard over the facets below it.
  const size_t ncam = m.cameras.size();
  std::vector<char> seen(ncam);
  for (size_t n = 0; n < count; ++n) {
    Node& node = h.nodes_[n];
    const OctreeRecord& r = m.octree[n];
    node.vertex = vec(r.vertex);
    node.normal = vec(r.normal);
    node.cone = r.cone;
    node.shape_error = r.shape_error;
    node.side = float(cells(r) * w0);
    float lo = 1, hi = 0;
    double reliability = 0;
    float least = 1;
    std::fill(seen.begin(), seen.end(), 0);
    for (uint32_t k = node.begin; k < node.end; ++k) {
      const FacetRecord& f = m.facets[h.order_[k]];
      const float d = (vec(f.center) - node.vertex).norm();
      node.radius = std::max(node.radius, d + 0.5f * std::sqrt(3.f) * f.size);
      node.surface_radius = std::max(node.surface_radius, d + 0.5f * f.size);
      if (!lum.empty()) {
        const float l = lum[h.order_[k]];
        if (std::isfinite(l)) lo = std::min(lo, l), hi = std::max(hi, l);
      }
      reliability += f.reliability;
      least = std::min(least, f.reliability);
      for (uint32_t j = 0; j < f.camera_count; ++j) seen[m.facet_cameras[f.first_camera + j]] = 1;
    }
    node.luminance_range = hi > lo ? hi - lo : 0.f;
    const uint32_t n_facets = node.end - node.begin;
    if (n_facets < 2) continue;
    FacetRecord b{};
    for (int k = 0; k < 3; ++k) b.center[k] = node.vertex[k];
    b.size = node.radius * 2 / std::sqrt(3.f);
    const bool has_cone = node.cone < kPi / 2 && node.normal.squaredNorm() > 0.25f;
    for (int k = 0; k < 3; ++k) b.normal[k] = has_cone ? node.normal[k] : 0.f;
    b.reliability = float(reliability / n_facets);
    b.first_camera = uint32_t(h.facet_cameras_.size());
    for (uint32_t c = 0; c < ncam; ++c)
      if (seen[c]) h.facet_cameras_.push_back(c);
    b.camera_count = uint32_t(h.facet_cameras_.size()) - b.first_camera;
    node.billboard = int32_t(h.facets_.size());
    h.facets_.push_back(b);
    h.least_reliability_.push_back(least);
  }
  return h;
}

void FacetHierarchy::emit_own(const Node& n, std::vector<uint32_t>& out) const {
  out.insert(out.end(), order_.begin() + n.begin, order_.begin() + n.own_end);
}

void FacetHierarchy::visit(int index, const Frame& f, std::vector<uint32_t>& out, LodStats& st) const {
  ++st.nodes_visited;
  const Node& n = nodes_[size_t(index)];
  const size_t below = n.end - n.begin;
  if (below == 0) return;
  const Eigen::Vector3d v = n.vertex.cast<double>();
  const Eigen::Vector3d to_node = v - f.eye;
  const double d_o = to_node.norm();
  const double r = n.radius;
  if (sphere_outside_view(f.camera_from_world, *f.K, v, r, f.near_m)) {
    st.facets_outside_frustum += below;
    return;
  }
  const double spread = d_o > r ? std::asin(r / d_o) : kPi;  // the node's angular radius
  double level = 1;
  if (f.field && d_o > r) {
    // The field's level at the node's point nearest the gaze.
    const Eigen::Vector3d& fwd = f.field->forward;
    const double off = angle_between(fwd, to_node);
    Eigen::Vector3d nearest = fwd;
    if (off > spread) {
      const Eigen::Vector3d axis = to_node.cross(fwd);
      nearest = axis.norm() > 0 ? Eigen::AngleAxisd(spread, axis.normalized()) * to_node : to_node;
    }
    level = field_level(*f.field, nearest);
    if (level <= 0) {
      st.facets_outside_field += below;
      return;
    }
  }
  const bool has_cone = n.cone < kPi / 2 && n.normal.squaredNorm() > 0.25f;
  const Eigen::Vector3d normal = n.normal.cast<double>();
  const double gamma = d_o > 0 ? angle_between(normal, -to_node) : 0;
  if (has_cone && gamma - n.cone - spread > f.back_angle + kConeMargin) {
    st.facets_back_cone += below;
    return;
  }
  if (n.billboard >= 0 && d_o > r) {
    bool accept = true;
    // Contour: the cone reaches the silhouette (or has no axis).
    const bool contour = !has_cone || gamma >= kPi / 2 - n.cone;
    if (contour && n.shape_error * f.focal_px / d_o > f.o.shape_px / level) {
      ++st.refined_contour;
      accept = false;
    }
    if (accept) {
      const double l_s = f.focal_px * n.side * std::max(0.0, std::cos(gamma)) / d_o;  // eq. 9
      if (n.luminance_range * l_s > f.o.luminance / level) {
        ++st.refined_luminance;
        accept = false;
      }
    }
    if (accept) {
      const FacetRecord& b = facets_[size_t(n.billboard)];
      double alpha = kPi;
      for (uint32_t j = 0; j < b.camera_count; ++j) {
        const Eigen::Vector3d to_cam = camera_centres_[facet_cameras_[b.first_camera + j]].cast<double>() - v;
        alpha = std::min(alpha, angle_between(to_cam, -to_node));
      }
      if (n.surface_radius * std::sin(std::min(alpha, kPi / 2)) * f.focal_px / d_o > f.o.texel_px / level) {
        ++st.refined_texel;
        accept = false;
      }
    }
    if (accept) {
      out.push_back(uint32_t(n.billboard));
      ++st.node_billboards;
      st.facets_replaced += below;
      return;
    }
  }
  emit_own(n, out);
  for (int c = 0; c < n.children; ++c) visit(n.first_child + c, f, out, st);
}

LodStats FacetHierarchy::select(const ViewCamera& view, const LodOptions& o, double near_m,
                                std::vector<uint32_t>& out) const {
  Stopwatch clock;
  LodStats st;
  out.clear();
  if (!o.enabled || nodes_.empty()) {
    out.resize(model_facets_);
    for (uint32_t i = 0; i < model_facets_; ++i) out[i] = i;
    st.loose_facets = nodes_.empty() ? model_facets_ : loose_.size();
    st.seconds = clock.seconds();
    return st;
  }
  Frame f;
  f.camera_from_world = view.world_from_camera.inverse();
  f.eye = view.eye();
  f.K = &view.K;
  f.focal_px = std::sqrt(view.K.fx * view.K.fy);
  f.near_m = near_m;
  f.back_angle = std::acos(std::clamp(o.backface_cos, -1.0, 1.0));
  f.o = o;
  if (o.field) {
    const Eigen::Vector2d g = o.gaze_px.value_or(Eigen::Vector2d(view.K.cx, view.K.cy));
    const Eigen::Vector3d ray((g.x() - view.K.cx) / view.K.fx, (g.y() - view.K.cy) / view.K.fy, 1);
    const Eigen::Matrix3d R = view.world_from_camera.linear();
    if (auto e = EyeFrame::look(R * ray, -R.col(1))) f.field = *e;
  }
  visit(0, f, out, st);
  out.insert(out.end(), loose_.begin(), loose_.end());
  st.loose_facets = loose_.size();
  st.seconds = clock.seconds();
  return st;
}

}  // namespace s2r
