#include "reconstruct/splat_composite.h"

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "core/parallel.h"
#include "reconstruct/splat_fit.h"
#include "reconstruct/splat_lanes.h"

namespace s2r {

// (Named, not anonymous: the compositor's buffers hold it.)
namespace composite_detail {
// One facet as this image sees it.
struct ProjectedFacet {
  float u, v;  // centre, pixels
  float k;     // 1 / (2 sigma^2), sigma in pixels
  float r2;    // squared radius of the box drawn: where alpha falls under 1/255, at most the cut
  float cut2;  // (3 sigma)^2: the footprint's cut
  float o;     // opacity
  float c[3];  // colour
};
}  // namespace composite_detail
using composite_detail::ProjectedFacet;

namespace {

constexpr int kCompositeTile = 16;

using simd::Lanes;
using simd::has_avx2;

double composite_ms_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

// Composites one tile's list (near to far) into `out`; true when every
// pixel became opaque before the list ended.
template <int N>
[[gnu::always_inline]] inline bool composite_tile_n(const std::vector<ProjectedFacet>& p, const uint64_t* list, uint32_t count, int x0, int y0, int w, int h, int W,
                    float* out) {
  using L = Lanes<N>;
  using vf = typename L::f;
  using vi = typename L::i;
  constexpr int G = kCompositeTile / N;  // lane groups a row
  vf T[kCompositeTile][G], R[kCompositeTile][G], Gr[kCompositeTile][G], B[kCompositeTile][G];
  vi done[kCompositeTile][G];
  vf lane_x[G];
  for (int g = 0; g < G; ++g) {
    lane_x[g] = L::iota(float(x0 + N * g));
    const vi past = L::iota(float(N * g)) >= L::all(float(w));  // lanes past the image's edge count as finished
    for (int y = 0; y < kCompositeTile; ++y) {
      T[y][g] = L::all(1.f), R[y][g] = Gr[y][g] = B[y][g] = L::all(0.f);
      done[y][g] = past;
    }
  }
  // Bit G y + g: the N pixels (y, N g ..) are still open. A facet whose
  // pixels are all finished costs one test.
  static_assert(kCompositeTile * G <= 64);
  uint64_t open = 0, row_starts = 0;  // row_starts: bit G y of every row
  for (int y = 0; y < kCompositeTile; ++y) row_starts |= uint64_t(1) << (G * y);
  for (int y = 0; y < h; ++y)
    for (int g = 0; g < (w + N - 1) / N; ++g) open |= uint64_t(1) << (G * y + g);
  const uint64_t all_rows = kCompositeTile * G == 64 ? ~uint64_t(0) : (uint64_t(1) << (kCompositeTile * G)) - 1;
  for (uint32_t j = 0; j < count && open; ++j) {
    if (j + 8 < count) __builtin_prefetch(&p[uint32_t(list[j + 8])]);  // the list is in depth order, the facets are not
    const ProjectedFacet& s = p[uint32_t(list[j])];
    const float r = std::sqrt(s.r2);
    const int ya = std::max(0, int(std::ceil(s.v - r)) - y0), yb = std::min(h - 1, int(std::floor(s.v + r)) - y0);
    const int xa = std::max(0, int(std::ceil(s.u - r)) - x0), xb = std::min(w - 1, int(std::floor(s.u + r)) - x0);
    if (ya > yb || xa > xb) continue;
    const int ga = xa / N, gb = xb / N;
    const uint64_t rows = (yb == kCompositeTile - 1 ? all_rows : (uint64_t(1) << (G * (yb + 1))) - 1) & ~((uint64_t(1) << (G * ya)) - 1);
    const uint64_t groups = (row_starts & rows) * (((uint64_t(1) << (gb - ga + 1)) - 1) << ga);
    for (uint64_t m = open & groups; m; m &= m - 1) {
      const int bit = __builtin_ctzll(m), y = bit / G, g = bit % G;
      const float dy = float(y0 + y) - s.v;
      const vf dx = lane_x[g] - s.u;
      const vf d2 = dx * dx + dy * dy;
      vf a = s.o * L::exp(-d2 * s.k);
      a = a < L::all(kSplatAlphaMax) ? a : L::all(kSplatAlphaMax);
      const vi dn = done[y][g];
      vi ok = (d2 <= L::all(s.cut2)) & (a >= L::all(kSplatAlphaMin)) & ~dn;
      const vf Tv = T[y][g];
      const vf next = Tv * (1.f - a);
      const vi fin = ok & (next < L::all(kSplatStopT));  // as the fit: this pixel is finished, the facet not added
      const vi now_done = dn | fin;
      done[y][g] = now_done;
      if (L::all_set(now_done)) open &= ~(uint64_t(1) << bit);
      ok &= ~fin;
      const vf aw = L::select(ok, a * Tv);
      R[y][g] += aw * s.c[0], Gr[y][g] += aw * s.c[1], B[y][g] += aw * s.c[2];
      T[y][g] = L::blend(ok, next, Tv);
    }
  }
  const bool finished = open == 0;
  for (int y = 0; y < h; ++y) {
    float* row = out + (size_t(y0 + y) * W + x0) * 4;
    for (int x = 0; x < w; ++x) {
      const int g = x / N, l = x % N;
      row[4 * x] = R[y][g][l], row[4 * x + 1] = Gr[y][g][l], row[4 * x + 2] = B[y][g][l], row[4 * x + 3] = T[y][g][l];
    }
  }
  return finished;
}

// The tile in 4 lanes, or in 8 with AVX2 where the processor has it.
#define S2R_TILE_ARGS const std::vector<ProjectedFacet>&p, const uint64_t *list, uint32_t count, int x0, int y0, int w, int h, int W, float *out
bool composite_tile_4(S2R_TILE_ARGS) { return composite_tile_n<4>(p, list, count, x0, y0, w, h, W, out); }
#if defined(__x86_64__)
__attribute__((target("avx2"))) bool composite_tile_8(S2R_TILE_ARGS) {
  return composite_tile_n<8>(p, list, count, x0, y0, w, h, W, out);
}
bool composite_tile(int lanes, S2R_TILE_ARGS) {
  return lanes == 8 ? composite_tile_8(p, list, count, x0, y0, w, h, W, out) : composite_tile_4(p, list, count, x0, y0, w, h, W, out);
}
#else
bool composite_tile(int, S2R_TILE_ARGS) { return composite_tile_4(p, list, count, x0, y0, w, h, W, out); }
#endif
#undef S2R_TILE_ARGS

// A tile's entries (depth << 32 | facet) near to far, ties in the order
// given (facet order): a stable LSD radix sort on the depth's four bytes,
// passing over a byte every entry shares (the top ones, within a tile).
// Short lists by insertion. `tmp`: scratch of the same length.
void sort_tile(uint64_t* a, size_t n, std::vector<uint64_t>& tmp) {
  if (n < 48) {
    for (size_t i = 1; i < n; ++i) {
      const uint64_t e = a[i];
      const uint32_t d = uint32_t(e >> 32);
      size_t j = i;
      for (; j > 0 && uint32_t(a[j - 1] >> 32) > d; --j) a[j] = a[j - 1];
      a[j] = e;
    }
    return;
  }
  tmp.resize(n);
  uint64_t* from = a;
  uint64_t* to = tmp.data();
  for (int shift = 32; shift < 64; shift += 8) {
    uint32_t count[256] = {};
    for (size_t i = 0; i < n; ++i) ++count[(from[i] >> shift) & 0xff];
    if (count[(from[0] >> shift) & 0xff] == n) continue;  // every entry shares this byte
    uint32_t at = 0;
    for (uint32_t& c : count) {
      const uint32_t k = c;
      c = at;
      at += k;
    }
    for (size_t i = 0; i < n; ++i) to[count[(from[i] >> shift) & 0xff]++] = from[i];
    std::swap(from, to);
  }
  if (from != a) std::copy_n(from, n, a);
}

}  // namespace

struct SplatCompositor::Buffers {
  std::vector<ProjectedFacet> p;  // per facet; opacity 0: not drawn
  std::vector<uint32_t> depth;    // per facet: its depth's bits (a positive float's bits sort as the float)
  std::vector<uint32_t> start;    // per tile, its first entry in `list`
  std::vector<uint32_t> counts;   // per share of the facets and tile: entries, then where the share's go
  std::vector<size_t> drawn;      // per share
  std::vector<uint64_t> list;     // per tile, (depth << 32 | facet), sorted near to far in the tile's task
  std::vector<std::array<uint16_t, 4>> tile_range;  // per drawn facet: its tiles x0, x1, y0, y1 (the count's, for the fill)
  std::vector<uint8_t> early;
};

SplatCompositor::SplatCompositor() : b_(std::make_unique<Buffers>()) {}
SplatCompositor::~SplatCompositor() = default;
SplatCompositor::SplatCompositor(SplatCompositor&&) noexcept = default;
SplatCompositor& SplatCompositor::operator=(SplatCompositor&&) noexcept = default;

void SplatCompositor::composite(const std::vector<float>& records, int coeffs, const Intrinsics& K,
                                const Eigen::Isometry3d& world_from_camera, double near_m, std::vector<float>& rgba_out,
                                int threads, SplatCompositeStats* stats) {
  using clock = std::chrono::steady_clock;
  Buffers& b = *b_;
  SplatCompositeStats st;
  const int lanes = lanes_ == 4 || !has_avx2() ? 4 : 8;
  st.lanes = lanes;
  const int W = K.width, H = K.height;
  const size_t stride = size_t(5 + 3 * coeffs), n = records.size() / stride;
  st.facets = n;
  rgba_out.resize(size_t(W) * H * 4);

  // Project every facet, in chunks over the threads.
  auto t = clock::now();
  const Eigen::Isometry3f cfw = world_from_camera.inverse().cast<float>();
  const Eigen::Vector3f eye = world_from_camera.translation().cast<float>();
  const bool lens = K.has_distortion();
  constexpr size_t kChunk = 16384;
  b.p.resize(n);
  b.depth.resize(n);
  parallel_for(int((n + kChunk - 1) / kChunk), threads, [&](int ci) {
    float basis[kMaxShCoeffs];
    for (size_t i = size_t(ci) * kChunk; i < std::min(n, size_t(ci + 1) * kChunk); ++i) {
      const float* rec = &records[i * stride];
      ProjectedFacet& q = b.p[i];
      q.o = 0;
      const Eigen::Vector3f X(rec[0], rec[1], rec[2]);
      const Eigen::Vector3f pc = cfw * X;
      if (!(pc.z() > float(near_m)) || !(pc.z() > 1e-3f) || rec[4] < kSplatAlphaMin) continue;
      float u, v;
      if (lens) {
        const auto px = K.project(pc.cast<double>());
        if (!px) continue;
        u = float(px->x()), v = float(px->y());
      } else {
        u = float(K.fx) * pc.x() / pc.z() + float(K.cx);
        v = float(K.fy) * pc.y() / pc.z() + float(K.cy);
      }
      const ScreenFootprint fp = screen_footprint(rec[3] * float(K.fx) / pc.z(), rec[4], pixel_filter_px2_);
      const float sigma = std::max(fp.sigma, 1e-4f), o = fp.opacity;
      if (o < kSplatAlphaMin) continue;
      const float r2 = splat_box_r2(sigma, o);
      const float r = std::sqrt(r2);
      if (u + r < -0.5f || v + r < -0.5f || u - r > float(W) - 0.5f || v - r > float(H) - 0.5f) continue;
      q.u = u, q.v = v, q.k = 0.5f / (sigma * sigma), q.r2 = r2, q.cut2 = 9.f * sigma * sigma, q.o = o;
      sh_basis((X - eye).normalized(), coeffs, basis);
      for (int c = 0; c < 3; ++c) {
        float val = 0.5f;
        for (int k = 0; k < coeffs; ++k) val += rec[5 + k * 3 + c] * basis[k];
        q.c[c] = std::max(0.f, val);
      }
      const float z = pc.z();
      std::memcpy(&b.depth[i], &z, 4);
    }
  });
  st.ms_project = composite_ms_since(t);

  // Each tile's list, filled in facet order; each tile sorts its own.
  t = clock::now();
  const int tiles_x = (W + kCompositeTile - 1) / kCompositeTile, tiles_y = (H + kCompositeTile - 1) / kCompositeTile;
  const size_t tiles = size_t(tiles_x) * tiles_y;
  auto range = [&](const ProjectedFacet& q, int& x0, int& x1, int& y0, int& y1) {
    const float r = std::sqrt(q.r2);
    x0 = std::max(0, int(std::floor((q.u - r + 0.5f) / kCompositeTile)));
    x1 = std::min(tiles_x - 1, int(std::floor((q.u + r + 0.5f) / kCompositeTile)));
    y0 = std::max(0, int(std::floor((q.v - r + 0.5f) / kCompositeTile)));
    y1 = std::min(tiles_y - 1, int(std::floor((q.v + r + 0.5f) / kCompositeTile)));
  };
  // Counted and filled by each thread over its own share of the facets: a
  // tile's entries from share k follow those of share k - 1.
  const int parts = std::max(1, std::min(worker_count(threads), int(n / 65536) + 1));
  b.counts.assign(size_t(parts) * tiles, 0);
  b.tile_range.resize(n);
  b.drawn.assign(size_t(parts), 0);
  auto share = [&](int k, size_t& lo, size_t& hi) { lo = n * size_t(k) / size_t(parts), hi = n * size_t(k + 1) / size_t(parts); };
  parallel_for(parts, parts, [&](int k) {
    size_t lo, hi;
    share(k, lo, hi);
    uint32_t* count = &b.counts[size_t(k) * tiles];
    for (size_t i = lo; i < hi; ++i) {
      const ProjectedFacet& q = b.p[i];
      if (q.o == 0) continue;
      ++b.drawn[size_t(k)];
      int x0, x1, y0, y1;
      range(q, x0, x1, y0, y1);
      b.tile_range[i] = {uint16_t(x0), uint16_t(x1), uint16_t(y0), uint16_t(y1)};
      for (int ty = y0; ty <= y1; ++ty)
        for (int tx = x0; tx <= x1; ++tx)
          count[size_t(ty) * tiles_x + tx] += splat_reaches_tile(q.u, q.v, q.r2, tx, ty, kCompositeTile);
    }
  });
  b.start.assign(tiles + 1, 0);
  for (size_t t = 0; t < tiles; ++t) {
    uint32_t at = b.start[t];
    for (int k = 0; k < parts; ++k) {
      const uint32_t c = b.counts[size_t(k) * tiles + t];
      b.counts[size_t(k) * tiles + t] = at;  // now share k's first slot in tile t
      at += c;
    }
    b.start[t + 1] = at;
  }
  for (size_t d : b.drawn) st.drawn += d;
  b.list.resize(b.start[tiles]);
  parallel_for(parts, parts, [&](int k) {
    size_t lo, hi;
    share(k, lo, hi);
    uint32_t* fill = &b.counts[size_t(k) * tiles];
    for (size_t i = lo; i < hi; ++i) {
      if (b.p[i].o == 0) continue;
      const auto [x0, x1, y0, y1] = b.tile_range[i];
      const ProjectedFacet& q = b.p[i];
      const uint64_t entry = uint64_t(b.depth[i]) << 32 | uint64_t(i);
      for (int ty = y0; ty <= y1; ++ty)
        for (int tx = x0; tx <= x1; ++tx)
          if (splat_reaches_tile(q.u, q.v, q.r2, tx, ty, kCompositeTile)) b.list[fill[size_t(ty) * tiles_x + tx]++] = entry;
    }
  });
  st.tile_entries = b.list.size();
  st.ms_sort = composite_ms_since(t);

  t = clock::now();
  b.early.assign(tiles, 0);
  parallel_for(int(tiles), threads, [&](int tile) {
    const int tx = tile % tiles_x, ty = tile / tiles_x;
    const int x0 = tx * kCompositeTile, y0 = ty * kCompositeTile, w = std::min(kCompositeTile, W - x0),
              h = std::min(kCompositeTile, H - y0);
    const uint32_t lo = b.start[size_t(tile)], hi = b.start[size_t(tile) + 1];
    if (lo == hi) {
      for (int y = 0; y < h; ++y) {
        float* row = rgba_out.data() + (size_t(y0 + y) * W + x0) * 4;
        for (int x = 0; x < w; ++x) row[4 * x] = row[4 * x + 1] = row[4 * x + 2] = 0.f, row[4 * x + 3] = 1.f;
      }
      return;
    }
    thread_local std::vector<uint64_t> scratch;
    sort_tile(b.list.data() + lo, hi - lo, scratch);  // near to far, ties in facet order
    b.early[size_t(tile)] = composite_tile(lanes, b.p, b.list.data() + lo, hi - lo, x0, y0, w, h, W, rgba_out.data());
  });
  st.tiles_finished_early = size_t(std::count(b.early.begin(), b.early.end(), uint8_t(1)));
  st.ms_composite = composite_ms_since(t);
  if (stats) *stats = st;
}

std::vector<uint32_t> morton_order(size_t n, const std::function<Eigen::Vector3f(size_t)>& point) {
  if (n < 2) return {};
  Eigen::AlignedBox3f box;
  for (size_t i = 0; i < n; ++i) box.extend(point(i));
  const Eigen::Vector3f scale = (box.sizes().array().max(1e-9f)).inverse().matrix() * 2097151.f;  // 21 bits an axis
  auto spread = [](uint64_t v) {  // 21 bits to every third of 63
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
  };
  std::vector<std::pair<uint64_t, uint32_t>> key(n);
  bool sorted = true;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f q = (point(i) - box.min()).cwiseProduct(scale);
    key[i] = {spread(uint64_t(q.x())) | spread(uint64_t(q.y())) << 1 | spread(uint64_t(q.z())) << 2, uint32_t(i)};
    if (i && key[i].first < key[i - 1].first) sorted = false;
  }
  if (sorted) return {};
  std::sort(key.begin(), key.end());
  std::vector<uint32_t> order(n);
  for (size_t i = 0; i < n; ++i) order[i] = key[i].second;
  return order;
}

bool order_splats_spatially(std::vector<float>& records, int stride) {
  const size_t n = records.size() / size_t(stride);
  const auto order = morton_order(n, [&](size_t i) { return Eigen::Vector3f(&records[i * size_t(stride)]); });
  if (order.empty()) return false;
  std::vector<float> out(records.size());
  for (size_t i = 0; i < n; ++i) std::copy_n(&records[size_t(order[i]) * size_t(stride)], stride, &out[i * size_t(stride)]);
  records.swap(out);
  return true;
}

void composite_splats(const std::vector<float>& records, int coeffs, const Intrinsics& K,
                      const Eigen::Isometry3d& world_from_camera, double near_m, std::vector<float>& rgba_out, int threads,
                      SplatCompositeStats* stats, float pixel_filter_px2) {
  SplatCompositor c;
  c.set_pixel_filter(pixel_filter_px2);
  c.composite(records, coeffs, K, world_from_camera, near_m, rgba_out, threads, stats);
}

}  // namespace s2r
