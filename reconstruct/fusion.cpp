// The sparse volume on OpenVDB (the only translation unit that includes it).
#include "reconstruct/fusion.h"
#include "reconstruct/fusion_grids.h"
#include "reconstruct/mask_windows.h"

#include "core/progress.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <functional>
#include <limits>
#include <mutex>
#include <optional>

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <emmintrin.h>

namespace s2r {

namespace {

using openvdb::Coord;

void vdb_init() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

template <class F>
void in_arena(int threads, F&& f) {
  if (threads > 0) {
    tbb::task_arena arena(threads);
    arena.execute(f);
  } else {
    f();
  }
}

// The hull's progress line for one level of its coarse-to-fine carve.
std::string fmt_level(int k, int n) { return "hull: level " + std::to_string(k) + " of " + std::to_string(n); }

// A sphere's projected footprint as an inclusive pixel window (conservative by
// a pixel for lens distortion). Empty when the sphere reaches the camera plane.
struct Window {
  int x0, y0, x1, y1;
  bool inside(int w, int h) const { return x0 >= 0 && y0 >= 0 && x1 < w && y1 < h; }
  bool outside(int w, int h) const { return x1 < 0 || y1 < 0 || x0 >= w || y0 >= h; }
};
std::optional<Window> footprint(const Intrinsics& K, const Eigen::Vector3d& p_cam, double radius) {
  if (p_cam.z() - radius <= 1e-3) return std::nullopt;
  auto px = K.project(p_cam);
  if (!px) return std::nullopt;
  const double r = std::max(K.fx, K.fy) * radius / (p_cam.z() - radius) + 1.0;
  return Window{int(std::floor(px->x() - r + 0.5)), int(std::floor(px->y() - r + 0.5)),
                int(std::floor(px->x() + r + 0.5)), int(std::floor(px->y() + r + 0.5))};
}

std::vector<SdfSample> to_samples(const std::vector<std::pair<Eigen::Vector3i, float>>& s) {
  std::vector<SdfSample> out;
  out.reserve(s.size());
  for (const auto& [ijk, d] : s) out.push_back({ijk, d});
  return out;
}

// Reads voxels of one leaf node by offset (neighbours mostly lie in the
// voxel's own leaf); `holds` tells whether a coordinate is in it. Values and
// active states are the accessor's.
template <class Leaf>
struct LeafReader {
  const Leaf& leaf;
  const Coord origin;
  explicit LeafReader(const Leaf& l) : leaf(l), origin(l.origin()) {}
  bool holds(const Coord& c) const {
    constexpr int32_t kMask = ~int32_t(Leaf::DIM - 1);
    return (c.x() & kMask) == origin.x() && (c.y() & kMask) == origin.y() && (c.z() & kMask) == origin.z();
  }
  // Whether the voxel is active; its value in `v` either way.
  bool probe(const Coord& c, typename Leaf::ValueType& v) const {
    const openvdb::Index o = Leaf::coordToOffset(c);
    v = leaf.getValue(o);
    return leaf.isValueOn(o);
  }
};

Coord coord_of(const Eigen::Vector3d& p, double voxel) {
  const Eigen::Vector3d q = p / voxel;
  // Beyond +-2^30 voxels (kilometres at any voxel size) lround's own rule.
  if (!(q.cwiseAbs().maxCoeff() < double(1 << 30)))
    return Coord(int(std::lround(q.x())), int(std::lround(q.y())), int(std::lround(q.z())));
  return Coord(round_half_away(q.x()), round_half_away(q.y()), round_half_away(q.z()));
}

}  // namespace

float depth_reliability(int views, float spread_m, double sigma_m) {
  if (views < 2 || !(sigma_m > 0) || !std::isfinite(spread_m)) return 0.f;
  const double count = std::min(1.0, (views - 1) / 3.0);
  const double s = spread_m / sigma_m;
  return float(count * std::exp(-0.5 * s * s));
}

Backdrop border_backdrop(const ImageU8& color) {
  Backdrop b;
  if (color.empty()) return b;
  const int c = color.channels;
  std::vector<std::vector<int>> border{size_t(c)};
  auto add = [&](int x, int y) {
    for (int k = 0; k < c; ++k) border[size_t(k)].push_back(color.at(x, y, k));
  };
  for (int x = 0; x < color.width; ++x) add(x, 0), add(x, color.height - 1);
  for (int y = 1; y + 1 < color.height; ++y) add(0, y), add(color.width - 1, y);
  b.color.assign(static_cast<size_t>(c), 0);
  for (int k = 0; k < c; ++k) {
    auto& v = border[size_t(k)];
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    b.color[size_t(k)] = v[v.size() / 2];
    std::vector<int> dev(v.size());
    for (size_t i = 0; i < v.size(); ++i) dev[i] = std::abs(v[i] - b.color[size_t(k)]);
    std::nth_element(dev.begin(), dev.begin() + dev.size() / 2, dev.end());
    b.spread = std::max(b.spread, 1.4826 * dev[dev.size() / 2]);
  }
  return b;
}

std::optional<ImageU8> backdrop_mask(const ImageU8& color, double threshold, double* border_spread) {
  if (color.empty() || color.width < 4 || color.height < 4) return std::nullopt;
  const int c = color.channels;
  const Backdrop b = border_backdrop(color);
  const std::vector<int>& bg = b.color;
  const double spread = b.spread;
  if (border_spread) *border_spread = spread;
  if (spread > 12) return std::nullopt;  // not a backdrop
  const double thr = threshold > 0 ? threshold : std::max(20.0, 6 * spread);
  ImageU8 mask(color.width, color.height, 1, 0);
  for (int y = 0; y < color.height; ++y)
    for (int x = 0; x < color.width; ++x)
      for (int k = 0; k < c; ++k)
        if (std::abs(color.at(x, y, k) - bg[size_t(k)]) > thr) {
          mask.at(x, y) = 255;
          break;
        }
  return mask;
}


SparseVolume::SparseVolume(double voxel_m, double truncation_m, std::optional<Eigen::AlignedBox3d> crop)
    : impl_(std::make_unique<Impl>()) {
  vdb_init();
  impl_->voxel = voxel_m;
  impl_->tau = std::max(truncation_m, voxel_m);
  impl_->behind = std::min(impl_->tau, 1.5 * voxel_m);
  impl_->crop = crop;
  impl_->tsdf = TsdfGrid::create(openvdb::Vec3s(0.f));
  impl_->tsdf->setTransform(openvdb::math::Transform::createLinearTransform(voxel_m));
}

SparseVolume::~SparseVolume() = default;
double SparseVolume::voxel() const { return impl_->voxel; }
double SparseVolume::truncation() const { return impl_->tau; }
const FusionStats& SparseVolume::fusion_stats() const { return impl_->stats; }

namespace {

constexpr int kLeaf = openvdb::MaskTree::LeafNodeType::DIM;  // 8

// Where the crop box bounds the measured points (every point used lies in
// it), the leaves a view touches are bits of a grid over the box's leaves
// (16 KB for a 0.6 m box at 1.5 mm voxels): setting a bit costs less than
// touching a leaf of an OpenVDB mask tree, whose top node alone is 256 KB
// to clear for every view. Elsewhere, or for a grid over 2^24 leaves, the
// mask tree.
struct LeafGrid {
  bool used = false;
  Coord lo;
  std::array<size_t, 3> n{};
};

LeafGrid leaf_grid(const SparseVolume::Impl& m, int band) {
  LeafGrid g;
  if (m.crop && (m.crop->min().cwiseAbs().maxCoeff() / m.voxel) < double(1 << 28) &&
      (m.crop->max().cwiseAbs().maxCoeff() / m.voxel) < double(1 << 28)) {
    const Coord a = coord_of(m.crop->min(), m.voxel), b = coord_of(m.crop->max(), m.voxel);
    double cells = 1;
    for (int k = 0; k < 3; ++k) {
      g.lo[k] = (a[k] - band) & ~(kLeaf - 1);
      g.n[size_t(k)] = size_t((((b[k] + band) & ~(kLeaf - 1)) - g.lo[k]) / kLeaf + 1);
      cells *= double(g.n[size_t(k)]);
    }
    g.used = cells <= double(1 << 24);
  }
  return g;
}

// The leaf nodes a view's measured points reach within the truncation band.
struct Touched {
  std::vector<Coord> leaves;
  size_t used = 0, outside = 0;
};

Touched touched_leaves(const SparseVolume::Impl& m, const DepthObservation& v, int band, const LeafGrid& g) {
  Touched t;
  const ImageU16& depth = *v.depth;
  std::optional<openvdb::MaskTree> mask;
  std::optional<openvdb::tree::ValueAccessor<openvdb::MaskTree>> acc;
  std::vector<uint64_t> bits;
  if (g.used) {
    bits.assign((g.n[0] * g.n[1] * g.n[2] + 63) / 64, 0);
  } else {
    mask.emplace(false);
    acc.emplace(*mask);
  }
  auto touch = [&](int lx, int ly, int lz) {
    if (!g.used) {
      acc->touchLeaf(Coord(lx, ly, lz));
      return;
    }
    const size_t i = (size_t((lx - g.lo.x()) / kLeaf) * g.n[1] + size_t((ly - g.lo.y()) / kLeaf)) * g.n[2] +
                     size_t((lz - g.lo.z()) / kLeaf);
    bits[i >> 6] |= uint64_t(1) << (i & 63);
  };
  Coord last_lo(std::numeric_limits<int>::max()), last_hi = last_lo;
  const Intrinsics& K = v.intrinsics;
  const bool pinhole = !K.has_distortion();
  // Through a pinhole, unproject's own arithmetic inline, its per-column
  // factors made once; the pose's product written out in Eigen's order.
  std::vector<double> column(size_t(std::max(depth.width, 0)));
  for (int x = 0; x < depth.width; x += 2) column[size_t(x)] = (x - K.cx) / K.fx;
  const Eigen::Matrix3d R = v.world_from_camera.linear();
  const Eigen::Vector3d T = v.world_from_camera.translation();
  for (int y = 0; y < depth.height; y += 2) {
    const double row = (y - K.cy) / K.fy;
    for (int x = 0; x < depth.width; x += 2) {
      const uint16_t d = depth.data[size_t(y) * depth.width + x];
      if (d == 0) continue;
      Eigen::Vector3d pc;
      if (pinhole) {
        const double z = d * v.unit_m;
        pc = Eigen::Vector3d(column[size_t(x)] * z, row * z, 1.0 * z);
      } else {
        auto u = K.unproject({double(x), double(y)}, d * v.unit_m);
        if (!u) continue;
        pc = *u;
      }
      const Eigen::Vector3d pw(R(0, 0) * pc.x() + R(0, 1) * pc.y() + R(0, 2) * pc.z() + T.x(),
                               R(1, 0) * pc.x() + R(1, 1) * pc.y() + R(1, 2) * pc.z() + T.y(),
                               R(2, 0) * pc.x() + R(2, 1) * pc.y() + R(2, 2) * pc.z() + T.z());
      if (!m.in_crop(pw)) {
        ++t.outside;
        continue;
      }
      ++t.used;
      const Coord c = coord_of(pw, m.voxel);
      Coord lo, hi;
      for (int a = 0; a < 3; ++a) lo[a] = (c[a] - band) & ~(kLeaf - 1), hi[a] = (c[a] + band) & ~(kLeaf - 1);
      if (lo == last_lo && hi == last_hi) continue;  // neighbouring pixels: the same leaves
      last_lo = lo, last_hi = hi;
      for (int lx = lo.x(); lx <= hi.x(); lx += kLeaf)
        for (int ly = lo.y(); ly <= hi.y(); ly += kLeaf)
          for (int lz = lo.z(); lz <= hi.z(); lz += kLeaf) touch(lx, ly, lz);
    }
  }
  if (g.used) {
    for (size_t w = 0; w < bits.size(); ++w)
      for (uint64_t b = bits[w]; b; b &= b - 1) {
        size_t i = w * 64 + size_t(std::countr_zero(b));
        const int z = int(i % g.n[2]);
        i /= g.n[2];
        const int y = int(i % g.n[1]), x = int(i / g.n[1]);
        t.leaves.push_back(g.lo.offsetBy(x * kLeaf, y * kLeaf, z * kLeaf));
      }
  } else {
    for (auto leaf = mask->cbeginLeaf(); leaf; ++leaf) t.leaves.push_back(leaf->origin());
  }
  return t;
}

// Touched leaves with the views that touched them, sorted so that each
// leaf's views are one run, in view order.
struct LeafRuns {
  std::vector<std::pair<Coord, uint32_t>> pairs;  // (leaf, view)
  std::vector<size_t> starts;                     // each leaf's run in `pairs`, and pairs.size()
};

// Leaves along a Morton curve: consecutive leaves are neighbours in space, so
// they project near each other in every view and the depth pixels they read
// stay in cache. (Each leaf's updates are its own: the order of leaves
// changes no value.)
LeafRuns morton_runs(std::vector<std::pair<Coord, uint32_t>> pairs) {
  auto morton = [](const Coord& c) {
    auto spread = [](int v) {  // 21 bits (leaf units, offset) to every third of 63
      uint64_t x = uint64_t(uint32_t(v / kLeaf + (1 << 20))) & 0x1fffff;
      x = (x | x << 32) & 0x1f00000000ffffULL, x = (x | x << 16) & 0x1f0000ff0000ffULL;
      x = (x | x << 8) & 0x100f00f00f00f00fULL, x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
      return (x | x << 2) & 0x1249249249249249ULL;
    };
    return spread(c.x()) | spread(c.y()) << 1 | spread(c.z()) << 2;
  };
  // Beyond 2^20 leaves from the origin two leaves may share a key: then by
  // coordinate. A leaf's views stay in view order (a view touches a leaf
  // once). Keys made once per pair, not per comparison.
  struct Keyed {
    uint64_t key;
    Coord leaf;
    uint32_t view;
  };
  std::vector<Keyed> keyed;
  keyed.reserve(pairs.size());
  for (const auto& [c, vi] : pairs) keyed.push_back({morton(c), c, vi});
  std::sort(keyed.begin(), keyed.end(), [](const Keyed& a, const Keyed& b) {
    if (a.key != b.key) return a.key < b.key;
    if (a.leaf != b.leaf) return a.leaf < b.leaf;
    return a.view < b.view;
  });
  LeafRuns runs;
  runs.pairs = std::move(pairs);
  for (size_t i = 0; i < keyed.size(); ++i) runs.pairs[i] = {keyed[i].leaf, keyed[i].view};
  for (size_t i = 0; i < runs.pairs.size(); ++i)
    if (i == 0 || runs.pairs[i].first != runs.pairs[i - 1].first) runs.starts.push_back(i);
  runs.starts.push_back(runs.pairs.size());
  return runs;
}

// A view as the projective update reads it; in a leaf, the voxels' camera
// coordinates step by one voxel along each grid axis (`step`'s columns).
struct UpdateView {
  const DepthObservation* obs;
  Eigen::Isometry3d cam_from_world;
  Eigen::Matrix3f step;
  float fx, fy, cx, cy, unit;
  bool pinhole;
};

// A voxel's update from its signed distance sdf = d - z (d the measured
// depth, z the voxel's), not far behind the surface: a running mean of the
// clamped distance, the count, and the running sum of squares (Welford).
inline void update_voxel(openvdb::Vec3s& vv, float sdf, float tau, float behind) {
  const float s = std::clamp(sdf, -behind, tau);
  const float n = vv[1] + 1.f;
  const float delta = s - vv[0];
  vv[0] += delta / n;
  vv[2] += delta * (s - vv[0]);
  vv[1] = n;
}

// The fusion kernel: one row of a leaf (D voxels along the grid's z) updated
// from a pinhole view. The row is projected four voxels at a time (SSE2, the
// scalar arithmetic's operations in its order), then only the voxels that
// land on the image read their pixels and only those with a measured depth
// not far behind them are updated: the branches follow the set bits, not each
// voxel's outcome. `crop_row`: the row's voxels inside the crop box (bits).
size_t fuse_row_pinhole(const UpdateView& c, const Eigen::Vector3f& row, int crop_row, float tau, float behind,
                        openvdb::Vec3s* line) {
  constexpr int D = kLeaf;
  const ImageU16& depth = *c.obs->depth;
  const float W = float(depth.width), H = float(depth.height);
  alignas(16) int ix[D], iy[D];
  alignas(16) float zs[D], sdf[D];
  alignas(16) float measured[D] = {};
  int on_image = 0;
  for (int h = 0; h < D; h += 4) {
    const __m128 k = _mm_setr_ps(float(h), float(h + 1), float(h + 2), float(h + 3));
    const __m128 x = _mm_add_ps(_mm_set1_ps(row.x()), _mm_mul_ps(_mm_set1_ps(c.step(0, 2)), k));
    const __m128 y = _mm_add_ps(_mm_set1_ps(row.y()), _mm_mul_ps(_mm_set1_ps(c.step(1, 2)), k));
    const __m128 z = _mm_add_ps(_mm_set1_ps(row.z()), _mm_mul_ps(_mm_set1_ps(c.step(2, 2)), k));
    const __m128 inv = _mm_div_ps(_mm_set1_ps(1.f), z);
    // Nearest pixel (+0.5 then truncated); the comparisons also refuse NaN.
    const __m128 half = _mm_set1_ps(0.5f), zero = _mm_setzero_ps();
    const __m128 px = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_set1_ps(c.fx), _mm_mul_ps(x, inv)), _mm_set1_ps(c.cx)), half);
    const __m128 py = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_set1_ps(c.fy), _mm_mul_ps(y, inv)), _mm_set1_ps(c.cy)), half);
    const __m128 ok = _mm_and_ps(_mm_and_ps(_mm_cmpgt_ps(z, zero), _mm_and_ps(_mm_cmpge_ps(px, zero), _mm_cmpge_ps(py, zero))),
                                 _mm_and_ps(_mm_cmplt_ps(px, _mm_set1_ps(W)), _mm_cmplt_ps(py, _mm_set1_ps(H))));
    on_image |= _mm_movemask_ps(ok) << h;
    _mm_store_si128(reinterpret_cast<__m128i*>(ix + h), _mm_cvttps_epi32(px));
    _mm_store_si128(reinterpret_cast<__m128i*>(iy + h), _mm_cvttps_epi32(py));
    _mm_store_ps(zs + h, z);
  }
  on_image &= crop_row;
  if (!on_image) return 0;
  for (int b = on_image; b; b &= b - 1) {
    const int k = std::countr_zero(unsigned(b));
    measured[k] = float(depth.data[size_t(iy[k]) * size_t(depth.width) + size_t(ix[k])]);
  }
  int take = 0;
  for (int h = 0; h < D; h += 4) {
    const __m128 d = _mm_load_ps(measured + h);
    const __m128 f = _mm_sub_ps(_mm_mul_ps(d, _mm_set1_ps(c.unit)), _mm_load_ps(zs + h));
    _mm_store_ps(sdf + h, f);
    // A measured depth (not 0), and the voxel not far behind it.
    take |= _mm_movemask_ps(_mm_and_ps(_mm_cmpneq_ps(d, _mm_setzero_ps()), _mm_cmpge_ps(f, _mm_set1_ps(-tau)))) << h;
  }
  size_t updates = 0;
  for (int b = take; b; b &= b - 1) {
    const int k = std::countr_zero(unsigned(b));
    update_voxel(line[k], sdf[k], tau, behind);
    ++updates;
  }
  return updates;
}

// The same row through a lens with distortion, voxel by voxel.
size_t fuse_row_distorted(const UpdateView& c, const Eigen::Vector3f& row, int crop_row, float tau, float behind,
                          openvdb::Vec3s* line) {
  const ImageU16& depth = *c.obs->depth;
  const Intrinsics& K = c.obs->intrinsics;
  const float W = float(depth.width), H = float(depth.height);
  size_t updates = 0;
  for (int k = 0; k < kLeaf; ++k) {
    const Eigen::Vector3f pc = row + c.step.col(2) * float(k);
    if (!(pc.z() > 0)) continue;
    if (!(crop_row & (1 << k))) continue;
    const auto pp = K.project(pc.cast<double>());
    if (!pp) continue;
    const float px = float(pp->x()) + 0.5f, py = float(pp->y()) + 0.5f;
    if (!(px >= 0 && py >= 0 && px < W && py < H)) continue;
    if (const uint16_t d = depth.data[size_t(int(py)) * depth.width + size_t(int(px))]) {
      const float f = float(d) * c.unit - pc.z();
      if (!(f < -tau)) {  // far behind the surface: unknown
        update_voxel(line[k], f, tau, behind);
        ++updates;
      }
    }
  }
  return updates;
}

// One leaf (origin `o`) updated by all its views in order while it sits in
// cache: per voxel the same updates in the same order as one view after the
// other. The crop box is tested per voxel only where the leaf crosses it.
// `first`..`last`: the leaf's (leaf, view) pairs, views indexing `views`.
size_t fuse_leaf(const SparseVolume::Impl& m, const Coord& o, const std::vector<UpdateView>& views,
                 const std::pair<Coord, uint32_t>* first, const std::pair<Coord, uint32_t>* last, openvdb::Vec3s* val) {
  constexpr int D = kLeaf;
  const Eigen::Vector3d lo = m.centre(o), hi = m.centre(o.offsetBy(D - 1));
  const bool inside = !m.crop || (m.crop->contains(lo) && m.crop->contains(hi));
  const float tau = float(m.tau), behind = float(m.behind);
  size_t updates = 0;
  for (const auto* p = first; p != last; ++p) {
    const UpdateView& c = views[p->second];
    const Eigen::Vector3f base = (c.cam_from_world * lo).cast<float>();
    for (int i = 0; i < D; ++i)
      for (int j = 0; j < D; ++j) {
        const Eigen::Vector3f row = base + c.step.col(0) * float(i) + c.step.col(1) * float(j);
        int crop_row = (1 << D) - 1;
        if (!inside)
          for (int k = 0; k < D; ++k)
            if (!m.in_crop(m.centre(o.offsetBy(i, j, k)))) crop_row &= ~(1 << k);
        openvdb::Vec3s* line = val + (i * D + j) * D;
        updates += c.pinhole ? fuse_row_pinhole(c, row, crop_row, tau, behind, line)
                             : fuse_row_distorted(c, row, crop_row, tau, behind, line);
      }
  }
  return updates;
}

}  // namespace

void SparseVolume::integrate(const DepthObservation& v, int threads) { integrate(std::vector<DepthObservation>{v}, threads); }

// 1. Per view, the leaf nodes (8^3 voxels) within the truncation band of a
//    measured point, every voxel in them active (as block-based TSDFs do:
//    cheaper than dilating voxel by voxel). Every other pixel is enough to
//    find them. Views in parallel.
// 2. Each touched leaf with the views that touched it, in view order; the
//    leaves joined into the volume's topology.
// 3. Projective update of every touched voxel, leaf nodes in parallel (each
//    leaf's voxels are written by one task only).
void SparseVolume::integrate(const std::vector<DepthObservation>& views, int threads, const std::function<void()>& on_view) {
  Impl& m = *impl_;
  const int band = int(std::ceil(m.tau / m.voxel));
  const LeafGrid grid = leaf_grid(m, band);
  std::vector<Touched> touched(views.size());
  in_arena(threads, [&] {
    tbb::parallel_for(size_t(0), views.size(), [&](size_t vi) {
      if (views[vi].depth && !views[vi].depth->empty()) touched[vi] = touched_leaves(m, views[vi], band, grid);
    });
  });

  std::vector<std::pair<Coord, uint32_t>> pairs;
  for (size_t vi = 0; vi < views.size(); ++vi) {
    ++m.stats.views;
    const Touched& t = touched[vi];
    m.stats.samples_outside_crop += t.outside;
    m.stats.depth_samples += t.used;
    if (t.used == 0) ++m.stats.views_without_depth;
    for (const Coord& c : t.leaves) pairs.emplace_back(c, uint32_t(vi));
  }
  auto views_done = [&] {
    if (on_view)
      for (size_t vi = 0; vi < views.size(); ++vi) on_view();
  };
  if (pairs.empty()) return views_done();
  const LeafRuns runs = morton_runs(std::move(pairs));
  {
    openvdb::tree::ValueAccessor<TsdfTree> acc(m.tsdf->tree());
    for (size_t g = 0; g + 1 < runs.starts.size(); ++g) acc.touchLeaf(runs.pairs[runs.starts[g]].first)->setValuesOn();
  }

  std::vector<UpdateView> vd(views.size());
  for (size_t vi = 0; vi < views.size(); ++vi) {
    const DepthObservation& v = views[vi];
    const Intrinsics& K = v.intrinsics;
    vd[vi].obs = &v;
    vd[vi].cam_from_world = v.world_from_camera.inverse();
    vd[vi].step = (vd[vi].cam_from_world.linear() * m.voxel).cast<float>();
    vd[vi].fx = float(K.fx), vd[vi].fy = float(K.fy), vd[vi].cx = float(K.cx), vd[vi].cy = float(K.cy);
    vd[vi].unit = float(v.unit_m);
    vd[vi].pinhole = !K.has_distortion();
  }
  std::atomic<size_t> updates{0};
  in_arena(threads, [&] {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, runs.starts.size() - 1), [&](const auto& range) {
      size_t local = 0;
      openvdb::tree::ValueAccessor<const TsdfTree> acc(m.tsdf->tree());
      for (size_t g = range.begin(); g != range.end(); ++g) {
        const Coord o = runs.pairs[runs.starts[g]].first;
        auto* dst = const_cast<TsdfTree::LeafNodeType*>(acc.probeConstLeaf(o));
        if (!dst) continue;
        local += fuse_leaf(m, o, vd, runs.pairs.data() + runs.starts[g], runs.pairs.data() + runs.starts[g + 1],
                           dst->buffer().data());
      }
      updates += local;
    });
  });
  m.stats.voxel_updates += updates.load();
  views_done();
}

namespace {

// One voxel against depth views: in how many is its footprint wholly
// measured (`seen`), in front of every sample by `margin` (`free`), wholly
// behind all of them by `hidden` (`behind`). A footprint with a hole or
// leaving the image gives no verdict. Stops once `enough_free` views say free.
struct DepthCounts {
  int free = 0, behind = 0, seen = 0;
};
DepthCounts depth_counts(const std::vector<DepthObservation>& depth, const std::vector<Eigen::Isometry3d>& cam_from_world,
                         const Eigen::Vector3d& centre, double radius, double margin, double hidden, int enough_free) {
  DepthCounts n;
  for (size_t k = 0; k < depth.size() && n.free < enough_free; ++k) {
    const ImageU16* im = depth[k].depth;
    if (!im || im->empty()) continue;
    const Eigen::Vector3d pc = cam_from_world[k] * centre;
    auto win = footprint(depth[k].intrinsics, pc, radius);
    if (!win || !win->inside(im->width, im->height)) continue;
    uint16_t lo_d = 0xffff, hi_d = 0;
    bool hole = false;
    for (int y = win->y0; y <= win->y1 && !hole; ++y)
      for (int x = win->x0; x <= win->x1; ++x) {
        const uint16_t d = im->data[size_t(y) * im->width + x];
        if (d == 0) {
          hole = true;
          break;
        }
        lo_d = std::min(lo_d, d), hi_d = std::max(hi_d, d);
      }
    if (hole) continue;
    ++n.seen;
    if (pc.z() + margin < lo_d * depth[k].unit_m) ++n.free;
    else if (pc.z() - hidden > hi_d * depth[k].unit_m) ++n.behind;
  }
  return n;
}

// Without depth the evidence is the hull's boundary: voxels beside empty space.
void mark_hull_boundary(SparseVolume::Impl& m) {
  m.fuzzy->clear();
  auto hacc = m.hull->getConstAccessor();
  auto facc = m.fuzzy->getAccessor();
  for (auto it = m.hull->cbeginValueOn(); it; ++it) {
    const Coord c = it.getCoord();
    bool boundary = false;
    for (int a = 0; a < 3 && !boundary; ++a)
      for (int sgn : {-1, 1}) {
        Coord n = c;
        n[a] += sgn;
        if (!hacc.isValueOn(n)) {
          boundary = true;
          break;
        }
      }
    if (boundary) facc.setValueOn(c);
  }
}

}  // namespace

HullStats SparseVolume::carve_hull(const std::vector<SilhouetteObservation>& views,
                                   const std::vector<DepthObservation>& depth, const Eigen::AlignedBox3d& box,
                                   int threads) {
  Impl& m = *impl_;
  HullStats hs;
  m.hull_only = depth.empty();
  struct ViewData {
    MaskWindows table;
    Eigen::Isometry3d cam_from_world;
    const Intrinsics* K;
  };
  std::vector<ViewData> vd;
  vd.reserve(views.size());
  for (const auto& v : views)
    if (v.mask && !v.mask->empty()) vd.push_back({MaskWindows(*v.mask), v.world_from_camera.inverse(), &v.intrinsics});

  // Coarse to fine: a cell of level k spans 2^k voxels per axis.
  const double extent = box.sizes().maxCoeff();
  int top = 0;
  while (extent / (m.voxel * double(1 << top)) > 8 && top < 16) ++top;
  hs.levels = top + 1;
  const Coord lo = coord_of(box.min(), m.voxel), hi = coord_of(box.max(), m.voxel);
  std::vector<Coord> cells;  // in units of the level's cell
  {
    const int s = 1 << top;
    auto floordiv = [](int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); };
    for (int x = floordiv(lo.x(), s); x <= floordiv(hi.x(), s); ++x)
      for (int y = floordiv(lo.y(), s); y <= floordiv(hi.y(), s); ++y)
        for (int z = floordiv(lo.z(), s); z <= floordiv(hi.z(), s); ++z) cells.emplace_back(x, y, z);
  }
  // A cell whose window lies wholly inside the image and inside the
  // silhouette in every view has children that every view keeps: a child's
  // centre lies half the parent's radius from the parent's, so it projects
  // inside the parent's window (for any lens whose magnification does not
  // double across a cell), onto foreground. They are kept without a test.
  enum : uint8_t { kCarve, kKept, kInterior };
  std::vector<uint8_t> interior(cells.size(), 0);  // the cell's parent was kInterior
  for (int level = top; level >= 0; --level) {
    const int s = 1 << level;
    const double size = m.voxel * s;
    const double radius = 0.5 * std::sqrt(3.0) * size;
    std::vector<uint8_t> keep(cells.size(), kKept);
    // A line for the levels that take a while only (a million cells: some
    // seconds); the coarse ones pass in milliseconds.
    std::optional<SharedProgress> progress;
    if (cells.size() >= 1000000) progress.emplace(fmt_level(top - level + 1, top + 1), cells.size());
    in_arena(threads, [&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, cells.size()), [&](const auto& r) {
        if (progress) progress->tick(r.size());
        for (size_t i = r.begin(); i != r.end(); ++i) {
          if (interior[i]) {
            keep[i] = kInterior;
            continue;
          }
          const Coord& c = cells[i];
          // Centre of the cell spanning voxels [c*s, c*s + s - 1].
          const Eigen::Vector3d centre =
              (Eigen::Vector3d(c.x(), c.y(), c.z()) * s + Eigen::Vector3d::Constant(0.5 * (s - 1))) * m.voxel;
          bool inside_all = level > 0;  // the finest level has no children to spare
          for (const auto& v : vd) {
            auto win = footprint(*v.K, v.cam_from_world * centre, radius);
            if (!win) {  // the camera is at the cell: no verdict
              inside_all = false;
              continue;
            }
            if (inside_all && v.table.all(win->x0, win->y0, win->x1, win->y1)) continue;
            inside_all = false;
            if (!v.table.any(win->x0, win->y0, win->x1, win->y1)) {
              keep[i] = kCarve;
              break;
            }
          }
          if (keep[i] == kKept && inside_all) keep[i] = kInterior;
        }
      });
    });
    if (progress) progress->done();
    const size_t untested = size_t(std::count(interior.begin(), interior.end(), uint8_t(1)));
    hs.cells_tested += cells.size() - untested;
    hs.cells_interior += untested;
    std::vector<Coord> next;
    std::vector<uint8_t> next_interior;
    for (size_t i = 0; i < cells.size(); ++i) {
      if (keep[i] == kCarve) continue;
      if (level == 0) {
        next.push_back(cells[i]);
        continue;
      }
      for (int k = 0; k < 8; ++k) {
        next.emplace_back(cells[i].x() * 2 + (k & 1), cells[i].y() * 2 + ((k >> 1) & 1), cells[i].z() * 2 + ((k >> 2) & 1));
        next_interior.push_back(keep[i] == kInterior);
      }
    }
    cells.swap(next);
    interior.swap(next_interior);
  }
  // Crop to the box at the finest level.
  std::erase_if(cells, [&](const Coord& c) { return !box.contains(m.centre(c)) || !m.in_crop(m.centre(c)); });
  hs.hull_voxels = cells.size();

  // Depth tests on the finest voxels.
  enum Verdict : uint8_t { kKeep, kFree, kSolid, kObserved };
  std::vector<uint8_t> verdict(cells.size(), kKeep);
  if (!depth.empty()) {
    const double radius = 0.5 * std::sqrt(3.0) * m.voxel;
    // Free: in front of every depth sample of the footprint by the truncation
    // distance. Hidden: wholly behind all of them (by its half-diagonal).
    const double margin = std::max(m.tau, radius), hidden = radius;
    std::vector<Eigen::Isometry3d> cam_from_world;
    for (const auto& d : depth) cam_from_world.push_back(d.world_from_camera.inverse());
    std::optional<SharedProgress> progress;
    if (cells.size() >= 1000000) progress.emplace("hull: depth", cells.size());
    in_arena(threads, [&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, cells.size()), [&](const auto& r) {
        if (progress) progress->tick(r.size());
        auto acc = m.tsdf->getConstAccessor();
        for (size_t i = r.begin(); i != r.end(); ++i) {
          openvdb::Vec3s val;
          if (acc.probeValue(cells[i], val) && val[1] > 0) {
            verdict[i] = kObserved;
            continue;
          }
          const DepthCounts n = depth_counts(depth, cam_from_world, m.centre(cells[i]), radius, margin, hidden, 1);
          verdict[i] = n.free > 0 ? kFree : (n.seen > 0 && n.behind == n.seen) ? kSolid : kKeep;
        }
      });
    });
    if (progress) progress->done();
  }
  m.hull = openvdb::MaskGrid::create(false);
  m.fuzzy = openvdb::MaskGrid::create(false);
  m.hull->setTransform(m.tsdf->transform().copy());
  m.fuzzy->setTransform(m.tsdf->transform().copy());
  auto hacc = m.hull->getAccessor();
  auto facc = m.fuzzy->getAccessor();
  for (size_t i = 0; i < cells.size(); ++i) {
    switch (verdict[i]) {
      case kFree: ++hs.carved_by_depth; break;
      case kSolid: ++hs.solid_by_depth; break;
      case kObserved: hacc.setValueOn(cells[i]); break;
      default: hacc.setValueOn(cells[i]); facc.setValueOn(cells[i]);
    }
  }
  if (m.hull_only) mark_hull_boundary(m);
  hs.fuzzy_voxels = m.fuzzy->activeVoxelCount();
  return hs;
}

size_t SparseVolume::carve_free(const std::vector<DepthObservation>& depth, int min_views, double margin_m, int threads) {
  Impl& m = *impl_;
  if (!m.hull || depth.empty()) return 0;
  std::vector<Coord> cells;
  cells.reserve(m.hull->activeVoxelCount());
  for (auto it = m.hull->cbeginValueOn(); it; ++it) cells.push_back(it.getCoord());
  const double radius = 0.5 * std::sqrt(3.0) * m.voxel, margin = std::max(margin_m, radius);
  std::vector<Eigen::Isometry3d> cam_from_world;
  for (const auto& d : depth) cam_from_world.push_back(d.world_from_camera.inverse());
  std::vector<uint8_t> free(cells.size(), 0);
  in_arena(threads, [&] {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, cells.size()), [&](const auto& r) {
      for (size_t i = r.begin(); i != r.end(); ++i)
        free[i] = depth_counts(depth, cam_from_world, m.centre(cells[i]), radius, margin, radius, min_views).free >= min_views;
    });
  });
  size_t carved = 0;
  auto hacc = m.hull->getAccessor();
  auto facc = m.fuzzy->getAccessor();
  for (size_t i = 0; i < cells.size(); ++i)
    if (free[i]) {
      hacc.setValueOff(cells[i]);
      facc.setValueOff(cells[i]);
      ++carved;
    }
  if (m.hull_only) mark_hull_boundary(m);
  return carved;
}

std::vector<EvidenceVoxel> SparseVolume::evidence(double reliability_sigma_m) const {
  const Impl& m = *impl_;
  // Leaf nodes in parallel, each with its own accessor and list; the lists
  // joined in leaf order give the order of a serial pass over the tree.
  openvdb::tree::LeafManager<const TsdfGrid::TreeType> lm(m.tsdf->constTree());
  std::vector<std::vector<EvidenceVoxel>> per_leaf(lm.leafCount());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, lm.leafCount()), [&](const tbb::blocked_range<size_t>& range) {
    auto acc = m.tsdf->getConstAccessor();
    for (size_t li = range.begin(); li != range.end(); ++li) {
      std::vector<EvidenceVoxel>& out = per_leaf[li];
      const LeafReader<TsdfGrid::TreeType::LeafNodeType> here(lm.leaf(li));
      auto value = [&](const Coord& c, openvdb::Vec3s& v) {
        if (here.holds(c)) return here.probe(c, v) && v[1] > 0;
        return acc.probeValue(c, v) && v[1] > 0;
      };
      for (auto it = lm.leaf(li).cbeginValueOn(); it; ++it) {
        const openvdb::Vec3s v = *it;
        if (v[1] <= 0) continue;
        // Every test below needs |sdf| <= 3 w (a neighbour across the surface
        // within 2 w or 3 w, or |sdf| < w/2): free space and the band's far
        // side are passed over without reading a neighbour.
        if (std::abs(v[0]) > 3 * m.voxel) continue;
        const Coord c = it.getCoord();
        bool surface = false;
        Eigen::Vector3f grad = Eigen::Vector3f::Zero();
        for (int a = 0; a < 3; ++a) {
          openvdb::Vec3s nb[2];
          bool has[2];
          for (int k = 0; k < 2; ++k) {
            Coord n = c;
            n[a] += k ? 1 : -1;
            has[k] = value(n, nb[k]);
            if (has[k] && ((nb[k][0] < 0) != (v[0] < 0)) && std::abs(nb[k][0] - v[0]) <= 2 * m.voxel &&
                (std::abs(v[0]) < std::abs(nb[k][0]) || (std::abs(v[0]) == std::abs(nb[k][0]) && k == 1)))
              surface = true;
          }
          if (has[0] && has[1])
            grad[a] = (nb[1][0] - nb[0][0]) / 2;
          else if (has[1])
            grad[a] = nb[1][0] - v[0];
          else if (has[0])
            grad[a] = v[0] - nb[0][0];
        }
        if (!surface && grad.norm() > 0.3f * float(m.voxel)) {
          // The surface, locally a plane, cuts this voxel's cube without crossing
          // a line to a 6-neighbour's centre (it clips a corner or an edge): the
          // plane at distance |sdf| / |grad| meets the cube when that is at most
          // (w/2) |n|_1. Without these voxels a ray that meets the surface in
          // such a corner finds no facet within w/2 of it (holes in the render).
          const Eigen::Vector3f n = grad.normalized();
          const double dist = std::abs(v[0]) * m.voxel / grad.norm();
          if (dist <= 0.5 * m.voxel * n.lpNorm<1>()) {
            for (int dx = -1; dx <= 1 && !surface; ++dx)
              for (int dy = -1; dy <= 1 && !surface; ++dy)
                for (int dz = -1; dz <= 1 && !surface; ++dz) {
                  openvdb::Vec3s nb;
                  if ((dx || dy || dz) && value(c.offsetBy(dx, dy, dz), nb) && (nb[0] < 0) != (v[0] < 0) &&
                      std::abs(nb[0] - v[0]) <= 3 * m.voxel)
                    surface = true;
                }
          }
        }
        if (!surface && std::abs(v[0]) < 0.5 * m.voxel) {
          // No observed neighbour across the surface (an object about one voxel
          // thick): the voxel holds surface when its distance is the smallest around.
          surface = true;
          for (int a = 0; a < 3 && surface; ++a)
            for (int k = 0; k < 2; ++k) {
              Coord n = c;
              n[a] += k ? 1 : -1;
              openvdb::Vec3s nb;
              if (value(n, nb) && std::abs(nb[0]) < std::abs(v[0])) surface = false;
            }
        }
        if (!surface) continue;
        EvidenceVoxel e;
        e.ijk = Eigen::Vector3i(c.x(), c.y(), c.z());
        e.centre = m.centre(c).cast<float>();
        if (grad.norm() > 1e-12f) e.normal = grad.normalized();
        e.sdf_m = v[0];
        e.views = int(v[1]);
        e.spread_m = float(std::sqrt(std::max(0.f, v[2]) / v[1]));
        e.reliability = depth_reliability(e.views, e.spread_m, reliability_sigma_m);
        out.push_back(e);
      }
    }
  });
  std::vector<EvidenceVoxel> out;
  size_t total = 0;
  for (const auto& l : per_leaf) total += l.size();
  out.reserve(total);
  for (const auto& l : per_leaf) out.insert(out.end(), l.begin(), l.end());
  if (m.fuzzy) {
    auto hacc = m.hull->getConstAccessor();
    for (auto it = m.fuzzy->cbeginValueOn(); it; ++it) {
      const Coord c = it.getCoord();
      Eigen::Vector3f outward = Eigen::Vector3f::Zero();
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz)
            if ((dx || dy || dz) && !hacc.isValueOn(c.offsetBy(dx, dy, dz)))
              outward += Eigen::Vector3f(float(dx), float(dy), float(dz)).normalized();
      EvidenceVoxel e;
      e.ijk = Eigen::Vector3i(c.x(), c.y(), c.z());
      e.centre = m.centre(c).cast<float>();
      if (outward.norm() > 0.5f) e.normal = outward.normalized();
      e.fuzzy = true;
      out.push_back(e);
    }
  }
  return out;
}

std::vector<SurfaceCrossing> SparseVolume::crossings(double max_jump_voxels) const {
  const Impl& m = *impl_;
  // Silhouettes only: samples() makes the distances from the hull.
  if (m.tsdf->activeVoxelCount() == 0) return find_crossings(to_samples(samples()), m.voxel, max_jump_voxels);
  // A sample is an observed voxel (views > 0) of a leaf with a finite
  // distance, as samples() lists them; leaves in parallel, joined in leaf
  // order (the order of samples()).
  openvdb::tree::LeafManager<const TsdfGrid::TreeType> lm(m.tsdf->constTree());
  std::vector<std::vector<SurfaceCrossing>> per_leaf(lm.leafCount());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, lm.leafCount()), [&](const tbb::blocked_range<size_t>& range) {
    auto acc = m.tsdf->getConstAccessor();
    for (size_t li = range.begin(); li != range.end(); ++li) {
      const LeafReader<TsdfGrid::TreeType::LeafNodeType> here(lm.leaf(li));
      auto get = [&](const Eigen::Vector3i& p) -> std::optional<float> {
        const Coord c(p.x(), p.y(), p.z());
        openvdb::Vec3s v;
        if (here.holds(c)) {
          if (!here.probe(c, v)) return std::nullopt;
        } else {
          const auto* leaf = acc.probeConstLeaf(c);
          if (!leaf) return std::nullopt;
          const auto off = leaf->coordToOffset(c);
          if (!leaf->isValueOn(off)) return std::nullopt;
          v = leaf->getValue(off);
        }
        if (!(v[1] > 0) || !std::isfinite(v[0])) return std::nullopt;
        return v[0];
      };
      for (auto it = lm.leaf(li).cbeginValueOn(); it; ++it) {
        const openvdb::Vec3s v = *it;
        if (!(v[1] > 0) || !std::isfinite(v[0])) continue;
        // Across a crossing the two distances' magnitudes add up to at most
        // the jump: a sample further than that from the surface has none.
        if (std::abs(v[0]) > max_jump_voxels * m.voxel) continue;
        const Coord c = it.getCoord();
        const Eigen::Vector3i p(c.x(), c.y(), c.z());
        for (int a = 0; a < 3; ++a)
          if (auto x = crossing_at(p, a, v[0], m.voxel, max_jump_voxels, get)) per_leaf[li].push_back(*x);
      }
    }
  });
  size_t n = 0;
  for (const auto& l : per_leaf) n += l.size();
  std::vector<SurfaceCrossing> out;
  out.reserve(n);
  for (const auto& l : per_leaf) out.insert(out.end(), l.begin(), l.end());
  return out;
}

std::vector<Eigen::Vector3f> SparseVolume::fit_candidates(double band_m) const {
  const Impl& m = *impl_;
  std::vector<Eigen::Vector3f> out;
  if (m.hull)
    for (auto it = m.hull->cbeginValueOn(); it; ++it) out.push_back(m.centre(it.getCoord()).cast<float>());
  if (!m.hull || !m.hull_only)
    for (auto it = m.tsdf->cbeginValueOn(); it; ++it) {
      const openvdb::Vec3s v = *it;
      if (v[1] <= 0 || std::abs(v[0]) > band_m) continue;
      if (m.hull && m.hull->tree().isValueOn(it.getCoord())) continue;  // taken with the hull
      out.push_back(m.centre(it.getCoord()).cast<float>());
    }
  return out;
}

size_t SparseVolume::active_voxels() const {
  size_t n = impl_->tsdf->activeVoxelCount();
  if (impl_->hull) n += impl_->hull->activeVoxelCount();
  return n;
}

size_t SparseVolume::memory_bytes() const {
  size_t n = impl_->tsdf->memUsage();
  if (impl_->hull) n += impl_->hull->memUsage() + impl_->fuzzy->memUsage();
  return n;
}

}  // namespace s2r
