#include "reconstruct/splat_raster.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "reconstruct/splat_fit.h"
#include "reconstruct/splat_lanes.h"

namespace s2r::fit_detail {

namespace {

constexpr int kPixels = kTile * kTile;

// exp(x) for the footprints' x in [-4.5, 0]: 2^t as 2^floor(t) times a
// degree-6 polynomial of the fraction (relative error under 2e-5; the
// compositing rounds alpha far coarser). Lanes<N>::exp is the same in N lanes.
inline float fast_exp(float x) {
  const float t = std::max(x, -80.f) * 1.4426950408889634f;
  const float fi = std::floor(t), f = t - fi;
  const float p = 1.f + f * (0.69314718f + f * (0.24022651f + f * (0.05550411f + f * (0.00961813f + f * (0.00133336f + f * 0.00015404f)))));
  const uint32_t bits = uint32_t(int32_t(fi) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, 4);
  return p * scale;
}

// The footprint's pixel box inside the tile, tile coordinates; false when empty.
inline bool footprint(const Projected& p, const TileState& st, int& xa, int& xb, int& ya, int& yb) {
  const float r = std::sqrt(p.r2box);
  xa = std::max(0, int(std::ceil(p.u - r)) - st.x0), xb = std::min(st.w - 1, int(std::floor(p.u + r)) - st.x0);
  ya = std::max(0, int(std::ceil(p.v - r)) - st.y0), yb = std::min(st.h - 1, int(std::floor(p.v + r)) - st.y0);
  return xa <= xb && ya <= yb;
}

// The tile's place, every pixel clear; pixels past the image's edge done.
void start_tile(const SplatFrame& f, int tile, TileState& st) {
  const int tx = tile % f.tiles_x, ty = tile / f.tiles_x;
  st.x0 = tx * kTile, st.y0 = ty * kTile;
  st.w = std::min(kTile, f.width - st.x0), st.h = std::min(kTile, f.height - st.y0);
  const int32_t lo = int32_t(f.tile_start[size_t(tile)]), hi = int32_t(f.tile_start[size_t(tile) + 1]);
  for (int y = 0; y < kTile; ++y)
    for (int x = 0; x < kTile; ++x) {
      const int i = y * kTile + x;
      const bool inside = x < st.w && y < st.h;
      st.T[i] = 1.f;
      st.C[0][i] = st.C[1][i] = st.C[2][i] = st.C[3][i] = 0.f;
      st.done[i] = inside ? 0 : -1;
      st.end[i] = inside ? hi : lo;
    }
}

void finish_tile(const Behind& bg, TileState& st) {
  const int channels = bg.depth ? 4 : 3;
  for (int y = 0; y < st.h; ++y)
    for (int x = 0; x < st.w; ++x)
      for (int c = 0; c < channels; ++c)
        st.C[c][y * kTile + x] += st.T[y * kTile + x] * (c < 3 ? bg.at(st.x0 + x, st.y0 + y, c) : bg.depth_at(st.x0 + x, st.y0 + y));
}

// The scalar reference: pixel by pixel over each footprint's box.
void forward_scalar(const SplatFrame& f, int tile, TileState& st, bool depth) {
  const uint32_t lo = f.tile_start[size_t(tile)], hi = f.tile_start[size_t(tile) + 1];
  int alive = st.w * st.h;
  for (uint32_t j = lo; j < hi && alive > 0; ++j) {
    const Projected& p = f.p[f.tile_list[j]];
    int xa, xb, ya, yb;
    if (!footprint(p, st, xa, xb, ya, yb)) continue;
    for (int y = ya; y <= yb; ++y) {
      const float dy = float(st.y0 + y) - p.v;
      for (int x = xa; x <= xb; ++x) {
        const int i = y * kTile + x;
        if (st.done[i]) continue;
        const float dx = float(st.x0 + x) - p.u;
        const float d2 = dx * dx + dy * dy;
        if (d2 > p.r2max) continue;
        const float alpha = std::min(kSplatAlphaMax, p.o * fast_exp(-d2 * p.inv2s2));
        if (alpha < kSplatAlphaMin) continue;
        const float next = st.T[i] * (1.f - alpha);
        if (next < kSplatStopT) {
          st.done[i] = -1, st.end[i] = int32_t(j), --alive;
          continue;
        }
        const float w = alpha * st.T[i];
        for (int c = 0; c < 3; ++c) st.C[c][i] += w * p.c[c];
        if (depth) st.C[3][i] += w * p.dist;
        st.T[i] = next;
      }
    }
  }
}

void backward_scalar(const SplatFrame& f, int tile, TileState& st, const float* dC, float* S, Grad* G, bool depth) {
  const uint32_t lo = f.tile_start[size_t(tile)];
  int32_t last = int32_t(lo);
  for (int i = 0; i < kPixels; ++i) last = std::max(last, st.end[i]);
  for (int32_t j = last; j-- > int32_t(lo);) {
    const uint32_t pi = f.tile_list[size_t(j)];
    const Projected& p = f.p[pi];
    int xa, xb, ya, yb;
    if (!footprint(p, st, xa, xb, ya, yb)) continue;
    Grad acc{};
    bool touched = false;
    for (int y = ya; y <= yb; ++y) {
      const float dy = float(st.y0 + y) - p.v;
      for (int x = xa; x <= xb; ++x) {
        const int i = y * kTile + x;
        if (j >= st.end[i]) continue;
        const float dx = float(st.x0 + x) - p.u;
        const float d2 = dx * dx + dy * dy;
        if (d2 > p.r2max) continue;
        const float g = fast_exp(-d2 * p.inv2s2);
        const float raw = p.o * g;
        const float alpha = std::min(kSplatAlphaMax, raw);
        if (alpha < kSplatAlphaMin) continue;
        touched = true;
        const float inv = 1.f / (1.f - alpha);
        const float Ti = st.T[i] * inv;
        const float w = alpha * Ti;
        float dalpha = 0;
        for (int c = 0; c < 3; ++c) {
          const float d = dC[c * kPixels + i];
          acc.c[c] += d * w;
          dalpha += d * (p.c[c] * Ti - S[c * kPixels + i] * inv);
          S[c * kPixels + i] += p.c[c] * w;
        }
        if (depth) {
          const float d = dC[3 * kPixels + i];
          acc.dist += d * w;
          dalpha += d * (p.dist * Ti - S[3 * kPixels + i] * inv);
          S[3 * kPixels + i] += p.dist * w;
        }
        acc.weight += w;
        st.T[i] = Ti;
        if (raw >= kSplatAlphaMax) continue;  // clamped: no gradient to o or the footprint
        acc.o += dalpha * g;
        const float dg = dalpha * p.o * g * 2.f * p.inv2s2;
        // g = exp(-d2 / (2 s^2)): dg/ds = g d2 / s^3, dg/du = g dx / s^2.
        acc.sigma += dg * d2 / p.sigma;
        acc.u += dg * dx;
        acc.v += dg * dy;
      }
    }
    if (!touched) continue;
    Grad& gr = G[pi];
    for (int c = 0; c < 3; ++c) gr.c[c] += acc.c[c];
    gr.o += acc.o, gr.sigma += acc.sigma, gr.u += acc.u, gr.v += acc.v, gr.weight += acc.weight, gr.dist += acc.dist;
  }
}

// The same in N lanes: a footprint's box covers whole groups of N pixels of
// a row, the pixels outside its cut masked (as the scalar's box test and
// cut test do), so each pixel sees the same arithmetic in the same order.
template <int N, bool D>
[[gnu::always_inline]] inline void forward_n(const SplatFrame& f, int tile, TileState& st) {
  using L = simd::Lanes<N>;
  using vf = typename L::f;
  using vi = typename L::i;
  constexpr int G = kTile / N;  // lane groups a row
  static_assert(kTile * G <= 64);
  const uint32_t lo = f.tile_start[size_t(tile)], hi = f.tile_start[size_t(tile) + 1];
  vf lane_x[G];
  for (int g = 0; g < G; ++g) lane_x[g] = L::iota(float(st.x0 + N * g));
  // Bit G y + g: the N pixels (y, N g ..) are still open.
  uint64_t open = 0, row_starts = 0;
  for (int y = 0; y < kTile; ++y) row_starts |= uint64_t(1) << (G * y);
  for (int y = 0; y < st.h; ++y)
    for (int g = 0; g < (st.w + N - 1) / N; ++g) open |= uint64_t(1) << (G * y + g);
  const uint64_t all_rows = kTile * G == 64 ? ~uint64_t(0) : (uint64_t(1) << (kTile * G)) - 1;
  for (uint32_t j = lo; j < hi && open; ++j) {
    if (j + 8 < hi) __builtin_prefetch(&f.p[f.tile_list[j + 8]]);  // the list is in depth order, scattered in memory
    const Projected& p = f.p[f.tile_list[j]];
    int xa, xb, ya, yb;
    if (!footprint(p, st, xa, xb, ya, yb)) continue;
    const int ga = xa / N, gb = xb / N;
    const uint64_t rows = (yb == kTile - 1 ? all_rows : (uint64_t(1) << (G * (yb + 1))) - 1) & ~((uint64_t(1) << (G * ya)) - 1);
    const uint64_t groups = (row_starts & rows) * (((uint64_t(1) << (gb - ga + 1)) - 1) << ga);
    const vi jv = L::all_i(int32_t(j));
    for (uint64_t m = open & groups; m; m &= m - 1) {
      const int bit = __builtin_ctzll(m), y = bit / G, g = bit % G;
      const int i = y * kTile + g * N;
      const float dy = float(st.y0 + y) - p.v;
      const vf dx = lane_x[g] - p.u;
      const vf d2 = dx * dx + dy * dy;
      vf a = p.o * L::exp(-d2 * p.inv2s2);
      a = a < L::all(kSplatAlphaMax) ? a : L::all(kSplatAlphaMax);
      const vi dn = L::load(&st.done[i]);
      vi ok = (d2 <= L::all(p.r2max)) & (a >= L::all(kSplatAlphaMin)) & ~dn;
      if (!L::any_set(ok)) continue;
      const vf Tv = L::load(&st.T[i]);
      const vf next = Tv * (1.f - a);
      const vi fin = ok & (next < L::all(kSplatStopT));  // this pixel is finished, the facet not added
      const vi now_done = dn | fin;
      L::store(&st.done[i], now_done);
      L::store(&st.end[i], (jv & fin) | (L::load(&st.end[i]) & ~fin));
      if (L::all_set(now_done)) open &= ~(uint64_t(1) << bit);
      ok &= ~fin;
      const vf aw = L::select(ok, a * Tv);
      for (int c = 0; c < 3; ++c) L::store(&st.C[c][i], L::load(&st.C[c][i]) + aw * p.c[c]);
      if constexpr (D) L::store(&st.C[3][i], L::load(&st.C[3][i]) + aw * p.dist);
      L::store(&st.T[i], L::blend(ok, next, Tv));
    }
  }
}

template <int N, bool D>
[[gnu::always_inline]] inline void backward_n(const SplatFrame& f, int tile, TileState& st, const float* dC, float* S,
                                              Grad* G) {
  using L = simd::Lanes<N>;
  using vf = typename L::f;
  using vi = typename L::i;
  const uint32_t lo = f.tile_start[size_t(tile)];
  int32_t last = int32_t(lo);
  for (int i = 0; i < kPixels; ++i) last = std::max(last, st.end[i]);
  vf lane_x[kTile / N];
  for (int g = 0; g < kTile / N; ++g) lane_x[g] = L::iota(float(st.x0 + N * g));
  for (int32_t j = last; j-- > int32_t(lo);) {
    if (j - 8 >= int32_t(lo)) {
      const uint32_t ahead = f.tile_list[size_t(j - 8)];
      __builtin_prefetch(&f.p[ahead]);
      __builtin_prefetch(&G[ahead], 1);
    }
    const uint32_t pi = f.tile_list[size_t(j)];
    const Projected& p = f.p[pi];
    int xa, xb, ya, yb;
    if (!footprint(p, st, xa, xb, ya, yb)) continue;
    const vi jv = L::all_i(j);
    const float two_k = 2.f * p.inv2s2, inv_sigma = 1.f / p.sigma;
    vf ac0 = L::all(0.f), ac1 = ac0, ac2 = ac0, ao = ac0, as = ac0, au = ac0, av = ac0, aw = ac0, ad = ac0;
    bool touched = false;
    for (int y = ya; y <= yb; ++y) {
      const float dy = float(st.y0 + y) - p.v;
      for (int g = xa / N; g <= xb / N; ++g) {
        const int i = y * kTile + g * N;
        const vi valid = jv < L::load(&st.end[i]);
        if (!L::any_set(valid)) continue;
        const vf dx = lane_x[g] - p.u;
        const vf d2 = dx * dx + dy * dy;
        const vf gv = L::exp(-d2 * p.inv2s2);
        const vf raw = p.o * gv;
        const vf alpha = raw < L::all(kSplatAlphaMax) ? raw : L::all(kSplatAlphaMax);
        const vi ok = valid & (d2 <= L::all(p.r2max)) & (alpha >= L::all(kSplatAlphaMin));
        if (!L::any_set(ok)) continue;
        touched = true;
        const vf inv = 1.f / (1.f - alpha);
        const vf Tv = L::load(&st.T[i]);
        const vf Ti = Tv * inv;
        const vf w = alpha * Ti;
        const vf d0 = L::load(&dC[i]), d1 = L::load(&dC[kPixels + i]), d2c = L::load(&dC[2 * kPixels + i]);
        const vf S0 = L::load(&S[i]), S1 = L::load(&S[kPixels + i]), S2 = L::load(&S[2 * kPixels + i]);
        ac0 += L::select(ok, d0 * w), ac1 += L::select(ok, d1 * w), ac2 += L::select(ok, d2c * w);
        vf dalpha = d0 * (p.c[0] * Ti - S0 * inv);
        dalpha += d1 * (p.c[1] * Ti - S1 * inv);
        dalpha += d2c * (p.c[2] * Ti - S2 * inv);
        L::store(&S[i], S0 + L::select(ok, p.c[0] * w));
        L::store(&S[kPixels + i], S1 + L::select(ok, p.c[1] * w));
        L::store(&S[2 * kPixels + i], S2 + L::select(ok, p.c[2] * w));
        if constexpr (D) {
          const vf d3 = L::load(&dC[3 * kPixels + i]), S3 = L::load(&S[3 * kPixels + i]);
          ad += L::select(ok, d3 * w);
          dalpha += d3 * (p.dist * Ti - S3 * inv);
          L::store(&S[3 * kPixels + i], S3 + L::select(ok, p.dist * w));
        }
        aw += L::select(ok, w);
        L::store(&st.T[i], L::blend(ok, Ti, Tv));
        const vi free = ok & (raw < L::all(kSplatAlphaMax));  // clamped: no gradient to o or the footprint
        const vf dg = dalpha * p.o * gv * two_k;
        ao += L::select(free, dalpha * gv);
        as += L::select(free, dg * d2 * inv_sigma);
        au += L::select(free, dg * dx);
        av += L::select(free, dg * dy);
      }
    }
    if (!touched) continue;
    Grad& gr = G[pi];
    gr.c[0] += L::sum(ac0), gr.c[1] += L::sum(ac1), gr.c[2] += L::sum(ac2);
    gr.o += L::sum(ao), gr.sigma += L::sum(as), gr.u += L::sum(au), gr.v += L::sum(av), gr.weight += L::sum(aw);
    if constexpr (D) gr.dist += L::sum(ad);
  }
}

// Each width with and without the depth channel.
void forward_4(const SplatFrame& f, int tile, TileState& st, bool depth) {
  depth ? forward_n<4, true>(f, tile, st) : forward_n<4, false>(f, tile, st);
}
void backward_4(const SplatFrame& f, int tile, TileState& st, const float* dC, float* S, Grad* G, bool depth) {
  depth ? backward_n<4, true>(f, tile, st, dC, S, G) : backward_n<4, false>(f, tile, st, dC, S, G);
}
#if defined(__x86_64__)
__attribute__((target("avx2"))) void forward_8(const SplatFrame& f, int tile, TileState& st, bool depth) {
  depth ? forward_n<8, true>(f, tile, st) : forward_n<8, false>(f, tile, st);
}
__attribute__((target("avx2"))) void backward_8(const SplatFrame& f, int tile, TileState& st, const float* dC, float* S,
                                                Grad* G, bool depth) {
  depth ? backward_n<8, true>(f, tile, st, dC, S, G) : backward_n<8, false>(f, tile, st, dC, S, G);
}
#else
void forward_8(const SplatFrame& f, int tile, TileState& st, bool depth) { forward_4(f, tile, st, depth); }
void backward_8(const SplatFrame& f, int tile, TileState& st, const float* dC, float* S, Grad* G, bool depth) {
  backward_4(f, tile, st, dC, S, G, depth);
}
#endif

int lanes_for(int lanes) { return lanes == 0 ? widest_lanes() : lanes == 8 && !simd::has_avx2() ? 4 : lanes; }

}  // namespace

int widest_lanes() { return simd::has_avx2() ? 8 : 4; }

void tile_forward(const SplatFrame& f, int tile, const Behind& bg, TileState& st, int lanes) {
  start_tile(f, tile, st);
  switch (lanes_for(lanes)) {
    case 1: forward_scalar(f, tile, st, bg.depth); break;
    case 4: forward_4(f, tile, st, bg.depth); break;
    default: forward_8(f, tile, st, bg.depth); break;
  }
  finish_tile(bg, st);
}

void tile_backward(const SplatFrame& f, int tile, const Behind& bg, TileState& st, const float* dC, Grad* G, int lanes) {
  // What lies behind each splat as the walk reaches it, the background first.
  alignas(32) float S[4 * kPixels];
  const bool depth = bg.depth;
  for (int i = 0; i < kPixels; ++i) {
    const int x = i % kTile, y = i / kTile;
    const bool inside = x < st.w && y < st.h;
    for (int c = 0; c < 3; ++c) S[c * kPixels + i] = inside ? st.T[i] * bg.at(st.x0 + x, st.y0 + y, c) : 0.f;
    S[3 * kPixels + i] = inside && depth ? st.T[i] * bg.depth_at(st.x0 + x, st.y0 + y) : 0.f;
  }
  switch (lanes_for(lanes)) {
    case 1: backward_scalar(f, tile, st, dC, S, G, depth); break;
    case 4: backward_4(f, tile, st, dC, S, G, depth); break;
    default: backward_8(f, tile, st, dC, S, G, depth); break;
  }
}

}  // namespace s2r::fit_detail
