#include "reconstruct/octree.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <optional>
#include <unordered_map>

namespace s2r {

namespace {

uint64_t pack(const Eigen::Vector3i& v) {
  constexpr int64_t off = int64_t(1) << 20;
  return (uint64_t(int64_t(v.x()) + off) << 42) | (uint64_t(int64_t(v.y()) + off) << 21) | uint64_t(int64_t(v.z()) + off);
}

// A sparse grid of T in blocks of 8^3 (`empty` where nothing was put): the
// neighbour lookups of the build stay within a block and hit the last one
// looked up, instead of hashing every voxel.
template <typename T>
class BlockGrid {
 public:
  explicit BlockGrid(T empty) : empty_(empty) {}
  const T& get(const Eigen::Vector3i& p) const {
    const int64_t b = block_of(p);
    return b < 0 ? empty_ : blocks_[size_t(b)][offset(p)];
  }
  T& at(const Eigen::Vector3i& p) {
    int64_t b = block_of(p);
    if (b < 0) {
      b = int64_t(blocks_.size());
      blocks_.emplace_back();
      blocks_.back().fill(empty_);
      index_.emplace(key(p), uint32_t(b));
      last_key_ = key(p), last_ = b;
    }
    return blocks_[size_t(b)][offset(p)];
  }
  void reserve(size_t voxels) { index_.reserve(voxels / 64 + 16); }

 private:
  static uint64_t key(const Eigen::Vector3i& p) {
    return pack(Eigen::Vector3i(p.x() >> 3, p.y() >> 3, p.z() >> 3));
  }
  static size_t offset(const Eigen::Vector3i& p) { return size_t((p.x() & 7) << 6 | (p.y() & 7) << 3 | (p.z() & 7)); }
  int64_t block_of(const Eigen::Vector3i& p) const {
    const uint64_t k = key(p);
    if (k == last_key_) return last_;
    auto it = index_.find(k);
    last_key_ = k;
    last_ = it == index_.end() ? -1 : int64_t(it->second);
    return last_;
  }
  T empty_;
  std::unordered_map<uint64_t, uint32_t> index_;
  std::vector<std::array<T, 512>> blocks_;
  mutable uint64_t last_key_ = ~uint64_t(0);
  mutable int64_t last_ = -1;
};

// acos with its argument clamped: rounding puts dot products of unit vectors
// just outside [-1, 1].
float safe_acos(float x) { return std::acos(std::clamp(x, -1.f, 1.f)); }

struct Leaf {
  Eigen::Vector3i cell;
  Eigen::Vector3d sum_p = Eigen::Vector3d::Zero();
  Eigen::Vector3f sum_n = Eigen::Vector3f::Zero();  // its crossings' normals, added in crossing order
  Eigen::Vector3f first_n = Eigen::Vector3f::Zero();
  uint32_t count = 0;
  float cone = 0;  // the widest angle from the leaf's normal to a crossing's
  uint16_t flags = 0;
};

struct Tmp {
  Eigen::Vector3i origin;
  std::vector<int> children;  // indices into the next level
  int leaf = -1;              // finest level: index into leaves
};

}  // namespace

std::vector<SurfaceCrossing> find_crossings(const std::vector<SdfSample>& samples, double voxel, double max_jump_voxels) {
  BlockGrid<float> sdf(std::numeric_limits<float>::quiet_NaN());
  sdf.reserve(samples.size());
  for (const auto& s : samples)
    if (std::isfinite(s.sdf)) sdf.at(s.ijk) = s.sdf;
  auto get = [&](const Eigen::Vector3i& p) -> std::optional<float> {
    const float v = sdf.get(p);
    return std::isnan(v) ? std::nullopt : std::optional<float>(v);
  };
  std::vector<SurfaceCrossing> out;
  for (const auto& s : samples) {
    if (!std::isfinite(s.sdf)) continue;
    for (int a = 0; a < 3; ++a)
      if (auto c = crossing_at(s.ijk, a, s.sdf, voxel, max_jump_voxels, get)) out.push_back(*c);
  }
  return out;
}

SurfaceOctree SurfaceOctree::build(const std::vector<SdfSample>& samples, double voxel, double max_jump_voxels) {
  return build_from_crossings(find_crossings(samples, voxel, max_jump_voxels), voxel);
}

SurfaceOctree SurfaceOctree::build_from_crossings(const std::vector<SurfaceCrossing>& crossings, double voxel) {
  SurfaceOctree t;
  t.voxel_ = voxel;
  // The leaf cells around each crossing edge.
  BlockGrid<int> leaf_of(-1);
  std::vector<Leaf> leaves;
  std::vector<std::array<int, 4>> edge_leaf;  // leaves index, cyclic order around the edge
  edge_leaf.reserve(crossings.size());
  t.edges_.reserve(crossings.size());
  for (const SurfaceCrossing& x : crossings) {
    const Eigen::Vector3i p = x.p;
    const int a = x.axis;
    const Eigen::Vector3d point = (p.cast<double>() + double(x.t) * Eigen::Vector3d::Unit(a)) * voxel;
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    std::array<int, 4> ids{};
    const int order[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};  // counter-clockwise seen from +a
    for (int k = 0; k < 4; ++k) {
      const int db = order[k][0], dc = order[k][1];
      const Eigen::Vector3i cell = p - db * Eigen::Vector3i::Unit(b) - dc * Eigen::Vector3i::Unit(c);
      int& id = leaf_of.at(cell);
      if (id < 0) id = int(leaves.size()), leaves.push_back({cell});
      Leaf& l = leaves[size_t(id)];
      l.sum_p += point;
      if (l.count++ == 0) l.first_n = x.normal;
      l.sum_n += x.normal;
      l.flags |= uint16_t(1u << (a * 4 + db + 2 * dc));
      ids[size_t(k)] = id;
    }
    t.edges_.push_back({p, uint8_t(a), x.inside_first});
    edge_leaf.push_back(ids);
  }
  t.leaf_count_ = leaves.size();
  if (leaves.empty()) return t;

  // Each leaf's cone: the widest angle from its normal to a crossing's.
  auto leaf_normal = [](const Leaf& lf) {
    return lf.sum_n.norm() > 1e-6f ? Eigen::Vector3f(lf.sum_n.normalized()) : lf.first_n;
  };
  {
    std::vector<Eigen::Vector3f> normal(leaves.size());
    for (size_t i = 0; i < leaves.size(); ++i) normal[i] = leaf_normal(leaves[i]);
    for (size_t e = 0; e < crossings.size(); ++e)
      for (int id : edge_leaf[e]) leaves[size_t(id)].cone = std::max(leaves[size_t(id)].cone, safe_acos(normal[size_t(id)].dot(crossings[e].normal)));
  }

  // Levels, bottom-up.
  Eigen::Vector3i lo = leaves[0].cell, hi = leaves[0].cell;
  for (const auto& l : leaves) lo = lo.cwiseMin(l.cell), hi = hi.cwiseMax(l.cell);
  t.base_ = lo;
  const int extent = (hi - lo).maxCoeff() + 1;
  while ((1 << t.max_level_) < extent) ++t.max_level_;
  const int L = t.max_level_;
  std::vector<std::vector<Tmp>> level(size_t(L) + 1);
  for (size_t i = 0; i < leaves.size(); ++i) level[size_t(L)].push_back({leaves[i].cell - lo, {}, int(i)});
  for (int l = L - 1; l >= 0; --l) {
    std::unordered_map<uint64_t, int> parent;
    const int shift = L - l;
    for (size_t i = 0; i < level[size_t(l + 1)].size(); ++i) {
      const Eigen::Vector3i o = level[size_t(l + 1)][i].origin;
      const Eigen::Vector3i po((o.x() >> shift) << shift, (o.y() >> shift) << shift, (o.z() >> shift) << shift);
      auto [it, fresh] = parent.try_emplace(pack(po), int(level[size_t(l)].size()));
      if (fresh) level[size_t(l)].push_back({po, {}, -1});
      level[size_t(l)][size_t(it->second)].children.push_back(int(i));
    }
  }

  // Breadth-first layout: children contiguous, parents before children.
  std::vector<std::vector<int>> index(size_t(L) + 1);
  for (int l = 0; l <= L; ++l) index[size_t(l)].assign(level[size_t(l)].size(), -1);
  std::vector<std::pair<int, int>> order;  // (level, tmp index)
  order.push_back({0, 0});
  index[0][0] = 0;
  t.nodes_.push_back({});
  for (size_t q = 0; q < order.size(); ++q) {
    const auto [l, i] = order[q];
    const Tmp& tmp = level[size_t(l)][size_t(i)];
    OctreeNode& n = t.nodes_[q];
    n.origin = tmp.origin;
    n.level = l;
    n.size = 1 << (L - l);
    if (tmp.children.empty()) continue;
    n.first_child = int32_t(t.nodes_.size());
    n.children = uint8_t(tmp.children.size());
    for (int c : tmp.children) {
      index[size_t(l + 1)][size_t(c)] = int(t.nodes_.size());
      OctreeNode child;
      child.parent = int32_t(q);
      t.nodes_.push_back(child);
      order.push_back({l + 1, c});
    }
  }
  std::vector<int> leaf_node(leaves.size());
  for (size_t i = 0; i < level[size_t(L)].size(); ++i) leaf_node[size_t(level[size_t(L)][i].leaf)] = index[size_t(L)][i];
  t.edge_cells_.reserve(edge_leaf.size() * 4);
  for (const auto& ids : edge_leaf)
    for (int id : ids) t.edge_cells_.push_back(leaf_node[size_t(id)]);

  // Every node's finest descendants as a range of `finest`: counts bottom-up,
  // then each child's start after its elder siblings'.
  std::vector<uint32_t> below_count(t.nodes_.size(), 0), below_start(t.nodes_.size(), 0);
  for (size_t q = t.nodes_.size(); q-- > 0;) {
    const OctreeNode& n = t.nodes_[q];
    if (n.children == 0) below_count[q] = 1;
    if (n.parent >= 0) below_count[size_t(n.parent)] += below_count[q];
  }
  std::vector<int> finest(t.nodes_.empty() ? 0 : below_count[0]);
  for (size_t q = 0; q < t.nodes_.size(); ++q) {
    const OctreeNode& n = t.nodes_[q];
    if (n.children == 0) finest[below_start[q]] = int(q);
    uint32_t s = below_start[q];
    for (int c = n.first_child; c < n.first_child + n.children; ++c) below_start[size_t(c)] = s, s += below_count[size_t(c)];
  }
  // Node statistics, children before parents (reverse breadth-first order).
  for (size_t q = t.nodes_.size(); q-- > 0;) {
    OctreeNode& n = t.nodes_[q];
    const auto [l, i] = order[q];
    if (n.children == 0) {
      const Leaf& lf = leaves[size_t(level[size_t(l)][size_t(i)].leaf)];
      n.crossings = lf.count;
      n.vertex = (lf.sum_p / double(lf.count)).cast<float>();
      n.normal = leaf_normal(lf);
      n.cone = lf.cone;
      n.edge_flags = lf.flags;
      n.shape_error = 0;
      continue;
    }
    Eigen::Vector3d vsum = Eigen::Vector3d::Zero();
    Eigen::Vector3f nsum = Eigen::Vector3f::Zero();
    uint32_t count = 0;
    float child_error = 0;
    for (int c = n.first_child; c < n.first_child + n.children; ++c) {
      const OctreeNode& ch = t.nodes_[size_t(c)];
      vsum += ch.vertex.cast<double>() * ch.crossings;
      count += ch.crossings;
      nsum += ch.normal;
      child_error = std::max(child_error, ch.shape_error);
    }
    n.crossings = count;
    n.vertex = (vsum / double(count)).cast<float>();
    // Opposite children (a thin sheet seen from both sides): the sum vanishes
    // and the cone opens to pi.
    const bool opposite = nsum.norm() < 1e-4f;
    n.normal = opposite ? t.nodes_[size_t(n.first_child)].normal : Eigen::Vector3f(nsum.normalized());
    n.cone = 0;
    for (int c = n.first_child; c < n.first_child + n.children; ++c) {
      const OctreeNode& ch = t.nodes_[size_t(c)];
      n.cone = std::max(n.cone, safe_acos(n.normal.dot(ch.normal)) + ch.cone);
    }
    n.cone = opposite ? float(std::numbers::pi) : std::min(n.cone, float(std::numbers::pi));
    float top = -std::numeric_limits<float>::infinity(), bottom = std::numeric_limits<float>::infinity();
    for (uint32_t k = below_start[q]; k < below_start[q] + below_count[q]; ++k) {
      const int leaf = finest[k];
      const float h = n.normal.dot(t.nodes_[size_t(leaf)].vertex - n.vertex);
      top = std::max(top, h), bottom = std::min(bottom, h);
    }
    n.shape_error = std::max(top - bottom, child_error);
  }
  return t;
}

std::vector<int> SurfaceOctree::cut(double max_shape_error_m) const {
  std::vector<int> out, stack;
  if (nodes_.empty()) return out;
  stack.push_back(0);
  while (!stack.empty()) {
    const int i = stack.back();
    stack.pop_back();
    const OctreeNode& n = nodes_[size_t(i)];
    if (n.children == 0 || n.shape_error <= max_shape_error_m) {
      out.push_back(i);
      continue;
    }
    for (int c = n.first_child; c < n.first_child + n.children; ++c) stack.push_back(c);
  }
  std::sort(out.begin(), out.end());
  return out;
}

Mesh SurfaceOctree::patch_mesh(const std::vector<int>& cut) const {
  Mesh mesh;
  if (nodes_.empty()) return mesh;
  // Every node's representative in the cut: itself when selected, else its
  // parent's (parents come first); leaves with no selected ancestor stay themselves.
  std::vector<int> rep(nodes_.size(), -1);
  std::vector<uint8_t> selected(nodes_.size(), 0);
  for (int i : cut) selected[size_t(i)] = 1;
  for (size_t i = 0; i < nodes_.size(); ++i) {
    if (selected[i]) rep[i] = int(i);
    else if (nodes_[i].parent >= 0) rep[i] = rep[size_t(nodes_[i].parent)];
    if (rep[i] < 0 && nodes_[i].children == 0) rep[i] = int(i);
  }
  std::unordered_map<int, int> vertex_of;
  auto vid = [&](int node) {
    auto [it, fresh] = vertex_of.try_emplace(node, int(mesh.vertices.size()));
    if (fresh) mesh.vertices.push_back(nodes_[size_t(node)].vertex);
    return it->second;
  };
  for (size_t e = 0; e < edges_.size(); ++e) {
    int v[4];
    for (int k = 0; k < 4; ++k) v[k] = vid(rep[size_t(edge_cells_[e * 4 + size_t(k)])]);
    // Split as at the finest level, then drop what the cut collapsed: the
    // map from fine to coarse vertices keeps a closed surface closed.
    for (const auto& tri : {Eigen::Vector3i(v[0], v[1], v[2]), Eigen::Vector3i(v[0], v[2], v[3])}) {
      if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) continue;
      mesh.faces.push_back(edges_[e].inside_first ? tri : Eigen::Vector3i(tri[0], tri[2], tri[1]));
    }
  }
  return mesh;
}

size_t boundary_edges(const Mesh& mesh) {
  // Every edge as a sorted key; an edge used an odd number of times is open.
  std::vector<uint64_t> edges;
  edges.reserve(mesh.faces.size() * 3);
  for (const auto& f : mesh.faces)
    for (int k = 0; k < 3; ++k) {
      uint32_t a = uint32_t(f[k]), b = uint32_t(f[(k + 1) % 3]);
      if (a > b) std::swap(a, b);
      edges.push_back(uint64_t(a) << 32 | b);
    }
  std::sort(edges.begin(), edges.end());
  size_t odd = 0;
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j] == edges[i]) ++j;
    odd += (j - i) % 2;
    i = j;
  }
  return odd;
}

std::vector<OctreeRecord> octree_records(const SurfaceOctree& tree) {
  std::vector<OctreeRecord> out;
  out.reserve(tree.nodes().size());
  for (const auto& n : tree.nodes()) {
    OctreeRecord r{};
    for (int k = 0; k < 3; ++k)
      r.vertex[k] = n.vertex[k], r.normal[k] = n.normal[k], r.origin[k] = n.origin[k] + tree.base_cell()[k];
    r.cone = n.cone;
    r.shape_error = n.shape_error;
    r.first_child = n.first_child < 0 ? kNoChild : uint32_t(n.first_child);
    r.children = n.children;
    r.edge_flags = n.edge_flags;
    r.level = uint8_t(n.level);
    out.push_back(r);
  }
  return out;
}

}  // namespace s2r
