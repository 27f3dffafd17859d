#include "reconstruct/splat_fit.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <numeric>
#include <random>
#include <thread>

#include <spdlog/fmt/fmt.h>

#include "core/image_metrics.h"
#include "core/parallel.h"
#include "reconstruct/splat_composite.h"
#include "reconstruct/splat_raster.h"

namespace s2r {

namespace {

using fit_detail::Behind;
using fit_detail::Grad;
using fit_detail::kTile;
using fit_detail::Projected;
using fit_detail::SplatFrame;
using fit_detail::TileState;
constexpr float kCut = 3.f;  // the footprint is cut at 3 sigma

// SH constants in 3DGS's order.
constexpr float kC0 = 0.28209479177387814f;
constexpr float kC1 = 0.4886025119029199f;
constexpr float kC2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f, -1.0925484305920792f,
                          0.5462742152960396f};

float logit(float p) { return std::log(p / (1.f - p)); }

}  // namespace

void radix_sort(std::vector<std::pair<uint32_t, uint32_t>>& a, std::vector<std::pair<uint32_t, uint32_t>>* scratch) {
  if (a.size() < 2) return;
  std::vector<std::pair<uint32_t, uint32_t>> own;
  auto& tmp = scratch ? *scratch : own;
  tmp.resize(a.size());
  for (int shift = 0; shift < 32; shift += 8) {
    size_t count[257] = {};
    for (const auto& e : a) ++count[((e.first >> shift) & 0xff) + 1];
    if (count[((a.front().first >> shift) & 0xff) + 1] == a.size()) continue;  // every key shares this byte
    for (int i = 0; i < 256; ++i) count[i + 1] += count[i];
    for (const auto& e : a) tmp[count[(e.first >> shift) & 0xff]++] = e;
    a.swap(tmp);
  }
}

namespace {

Intrinsics scaled(const Intrinsics& K, int s) {
  if (s == 1) return K;
  Intrinsics k = K;
  k.width = K.width / s;
  k.height = K.height / s;
  k.fx = K.fx / s, k.fy = K.fy / s;
  k.cx = (K.cx + 0.5) / s - 0.5, k.cy = (K.cy + 0.5) / s - 0.5;
  return k;
}

}  // namespace

SplatFrame fit_detail::project(const std::vector<Splat>& splats, int coeffs, const Intrinsics& K,
                               const Eigen::Isometry3d& world_from_camera, int threads, float pixel_filter_px2) {
  SplatFrame f;
  project_into(f, splats, coeffs, K, world_from_camera, threads, pixel_filter_px2);
  return f;
}

void fit_detail::project_into(SplatFrame& f, const std::vector<Splat>& splats, int coeffs, const Intrinsics& K,
                              const Eigen::Isometry3d& world_from_camera, int threads, float pixel_filter_px2) {
  f.width = K.width, f.height = K.height;
  f.tiles_x = (K.width + kTile - 1) / kTile, f.tiles_y = (K.height + kTile - 1) / kTile;
  const Eigen::Isometry3f cfw = world_from_camera.inverse().cast<float>();
  const Eigen::Vector3f eye = world_from_camera.translation().cast<float>();
  const bool lens = K.has_distortion();
  const int n = int(splats.size());
  const int workers = std::max(1, std::min(worker_count(threads), n / 4096 + 1));
  auto& part = f.scratch.part;
  part.resize(size_t(workers));
  parallel_for(workers, workers, [&](int w) {
    auto& out = part[size_t(w)];
    const int lo = int(int64_t(n) * w / workers), hi = int(int64_t(n) * (w + 1) / workers);
    out.clear();
    out.reserve(size_t(hi - lo));
    float basis[kMaxShCoeffs];
    for (int i = lo; i < hi; ++i) {
      const Splat& s = splats[size_t(i)];
      const Eigen::Vector3f X = s.centre();
      const Eigen::Vector3f pc = cfw * X;
      if (!(pc.z() > 1e-3f)) continue;
      float u, v;
      if (lens) {
        auto px = K.project(pc.cast<double>());
        if (!px) continue;
        u = float(px->x()), v = float(px->y());
      } else {
        u = float(K.fx) * pc.x() / pc.z() + float(K.cx);
        v = float(K.fy) * pc.y() / pc.z() + float(K.cy);
      }
      const ScreenFootprint fp = screen_footprint(s.sigma() * float(K.fx) / pc.z(), s.opacity(), pixel_filter_px2);
      if (fp.opacity < kSplatAlphaMin) continue;
      const float sigma = std::max(fp.sigma, 1e-4f), r = kCut * fp.sigma;
      // A faint facet's alpha falls under 1/255 inside the cut: the passes
      // visit only that disc's box, the same pixels as the cut's box.
      const float r2box = splat_box_r2(sigma, fp.opacity);
      const float rb = std::sqrt(r2box);
      if (u + rb < -0.5f || v + rb < -0.5f || u - rb > K.width - 0.5f || v - rb > K.height - 0.5f) continue;
      Projected p;
      p.u = u, p.v = v;
      p.sigma = sigma;
      p.inv2s2 = 0.5f / (sigma * sigma);
      p.r2max = r * r;
      p.r2box = r2box;
      p.o = fp.opacity;
      p.sigma_gain = fp.sigma_gain, p.opacity_gain_sigma = fp.opacity_gain_sigma, p.opacity_gain = fp.opacity_gain;
      p.pc = pc;
      p.dist = pc.norm();
      p.id = uint32_t(i);
      p.clamped = 0;
      sh_basis((X - eye).normalized(), coeffs, basis);
      for (int c = 0; c < 3; ++c) {
        float val = 0.5f;
        for (int k = 0; k < coeffs; ++k) val += s.sh[size_t(k * 3 + c)] * basis[k];
        if (val < 0) val = 0, p.clamped |= uint8_t(1 << c);
        p.c[c] = val;
      }
      out.push_back(p);
    }
  });
  // The parts concatenated (ascending ids), and their depth keys sorted:
  // the tile lists are filled in that order, the facets stay in id order.
  std::vector<size_t> offset(part.size() + 1, 0);
  for (size_t w = 0; w < part.size(); ++w) offset[w + 1] = offset[w] + part[w].size();
  const size_t total = offset.back();
  f.p.resize(total);
  auto& keys = f.scratch.keys;
  keys.resize(total);
  parallel_for(workers, workers, [&](int w) {
    const auto& in = part[size_t(w)];
    std::copy(in.begin(), in.end(), f.p.begin() + std::ptrdiff_t(offset[size_t(w)]));
    for (size_t j = 0; j < in.size(); ++j) {
      uint32_t bits;
      std::memcpy(&bits, &in[j].pc.z(), 4);
      keys[offset[size_t(w)] + j] = {bits, uint32_t(offset[size_t(w)] + j)};
    }
  });
  radix_sort(keys, &f.scratch.keys_tmp);
  // Tile lists in depth order: counted and filled by each thread over its
  // own share of the sorted facets (a tile's entries from share k follow
  // those of share k - 1), the tile ranges kept from the count to the fill.
  const size_t tiles = size_t(f.tiles_x) * f.tiles_y;
  const int shares = std::max(1, std::min(worker_count(threads), int(total / 65536) + 1));
  auto& counts = f.scratch.counts;
  counts.assign(size_t(shares) * tiles, 0);
  auto& span = f.scratch.span;
  span.resize(total);
  auto share = [&](int k, size_t& lo, size_t& hi) { lo = total * size_t(k) / size_t(shares), hi = total * size_t(k + 1) / size_t(shares); };
  parallel_for(shares, shares, [&](int k) {
    size_t lo, hi;
    share(k, lo, hi);
    uint32_t* count = &counts[size_t(k) * tiles];
    for (size_t i = lo; i < hi; ++i) {
      const Projected& p = f.p[keys[i].second];
      const float r = std::sqrt(p.r2box);
      const int x0 = std::max(0, int(std::floor((p.u - r + 0.5f) / kTile)));
      const int x1 = std::min(f.tiles_x - 1, int(std::floor((p.u + r + 0.5f) / kTile)));
      const int y0 = std::max(0, int(std::floor((p.v - r + 0.5f) / kTile)));
      const int y1 = std::min(f.tiles_y - 1, int(std::floor((p.v + r + 0.5f) / kTile)));
      span[i] = {uint16_t(x0), uint16_t(std::max(x0 - 1, x1)), uint16_t(y0), uint16_t(std::max(y0 - 1, y1))};
      if (x0 == x1 || y0 == y1) {
        for (int ty = y0; ty <= y1; ++ty)
          for (int tx = x0; tx <= x1; ++tx) ++count[size_t(ty) * f.tiles_x + tx];
      } else {
        for (int ty = y0; ty <= y1; ++ty)
          for (int tx = x0; tx <= x1; ++tx) count[size_t(ty) * f.tiles_x + tx] += splat_reaches_tile(p.u, p.v, p.r2box, tx, ty, kTile);
      }
    }
  });
  f.tile_start.assign(tiles + 1, 0);
  for (size_t t = 0; t < tiles; ++t) {
    uint32_t at = f.tile_start[t];
    for (int k = 0; k < shares; ++k) {
      const uint32_t c = counts[size_t(k) * tiles + t];
      counts[size_t(k) * tiles + t] = at;  // now share k's first slot in tile t
      at += c;
    }
    f.tile_start[t + 1] = at;
  }
  f.tile_list.resize(f.tile_start[tiles]);
  parallel_for(shares, shares, [&](int k) {
    size_t lo, hi;
    share(k, lo, hi);
    uint32_t* fill = &counts[size_t(k) * tiles];
    for (size_t i = lo; i < hi; ++i) {
      const auto [x0, x1, y0, y1] = span[i];
      if (x0 == x1 || y0 == y1) {
        for (int ty = y0; ty <= y1; ++ty)
          for (int tx = x0; tx <= x1; ++tx) f.tile_list[fill[size_t(ty) * f.tiles_x + tx]++] = keys[i].second;
      } else {
        const Projected& p = f.p[keys[i].second];
        for (int ty = y0; ty <= y1; ++ty)
          for (int tx = x0; tx <= x1; ++tx)
            if (splat_reaches_tile(p.u, p.v, p.r2box, tx, ty, kTile)) f.tile_list[fill[size_t(ty) * f.tiles_x + tx]++] = keys[i].second;
      }
    }
  });
}

namespace {

// Tiles handed out one at a time; body(tile, thread).
void for_tiles(const SplatFrame& f, int threads, const std::function<void(int, int)>& body) {
  const int tiles = f.tiles_x * f.tiles_y;
  const int workers = std::max(1, std::min(worker_count(threads), tiles));
  std::atomic<int> next{0};
  parallel_for(workers, workers, [&](int w) {
    for (int t = next++; t < tiles; t = next++) body(t, w);
  });
}

}  // namespace

namespace fit_detail {

double forward_backward(const SplatFrame& f, const ImageU8& target, const Behind& bg, float scale, int threads,
                        std::vector<std::vector<Grad>>* grads_out, const Loss& loss, int lanes, double* depth_sq,
                        double* depth_px) {
  const float ssim_weight = loss.ssim_weight, depth_scale = loss.depth_scale;
  // d |e| / d e (0 at 0), or d e^2 / d e.
  const auto colour_slope = [l1 = loss.l1](float e) { return l1 ? float((e > 0) - (e < 0)) : 2.f * e; };
  const int workers = std::max(1, std::min(worker_count(threads), f.tiles_x * f.tiles_y));
  if (grads_out) {
    // Each thread's gradients, zeroed by both threads in chunks (at 600,000
    // facets two arrays of 22 MB a step).
    grads_out->resize(size_t(workers));
    constexpr size_t kChunk = 65536;
    const size_t n = f.p.size(), chunks = (n + kChunk - 1) / kChunk;
    for (auto& g : *grads_out) g.resize(n);
    parallel_for(int(chunks * grads_out->size()), threads, [&](int k) {
      auto& g = (*grads_out)[size_t(k) / chunks];
      const size_t lo = (size_t(k) % chunks) * kChunk;
      std::fill(g.begin() + std::ptrdiff_t(lo), g.begin() + std::ptrdiff_t(std::min(n, lo + kChunk)), Grad{});
    });
  }
  std::vector<double> err(size_t(workers), 0.0), derr(size_t(workers), 0.0), dpx(size_t(workers), 0.0);
  const int ch = target.channels;
  constexpr int kPixels = kTile * kTile;
  // The depth channel's derivative (its plane of dC) where the pixel has a
  // depth, zero elsewhere; its squared error and pixels summed.
  auto depth_error = [&](const TileState& st, float* dC, int wk) {
    if (!bg.depth) return;
    double e = 0, n = 0;
    std::fill(dC + 3 * kPixels, dC + 4 * kPixels, 0.f);
    for (int y = 0; y < st.h; ++y)
      for (int x = 0; x < st.w; ++x) {
        const float d = bg.depth_at(st.x0 + x, st.y0 + y);
        if (!(d > 0)) continue;
        const float diff = st.C[3][y * kTile + x] - d;
        e += double(diff) * diff, n += 1;
        dC[3 * kPixels + y * kTile + x] = 2.f * scale * depth_scale * diff;
      }
    derr[size_t(wk)] += e, dpx[size_t(wk)] += n;
  };
  auto depth_totals = [&] {
    if (depth_sq) *depth_sq += std::accumulate(derr.begin(), derr.end(), 0.0);
    if (depth_px) *depth_px += std::accumulate(dpx.begin(), dpx.end(), 0.0);
  };
  // The squared error's derivative by each pixel's colour, and the error.
  auto squared_error = [&](const TileState& st, float* dC) {
    double e = 0;
    std::fill(dC, dC + 3 * kPixels, 0.f);
    for (int y = 0; y < st.h; ++y)
      for (int x = 0; x < st.w; ++x) {
        const uint8_t* gt = &target.data[(size_t(st.y0 + y) * target.width + st.x0 + x) * ch];
        for (int c = 0; c < 3; ++c) {
          const float diff = st.C[c][y * kTile + x] - float(gt[c]) * (1.f / 255.f);
          e += double(diff) * diff;
          dC[c * kPixels + y * kTile + x] = scale * colour_slope(diff);
        }
      }
    return e;
  };
  if (ssim_weight > 0 && grads_out) {
    std::vector<TileState> states(size_t(f.tiles_x) * f.tiles_y);
    ImageF drawn(f.width, f.height, 3), photo(f.width, f.height, 3);
    for_tiles(f, threads, [&](int tile, int wk) {
      TileState& st = states[size_t(tile)];
      tile_forward(f, tile, bg, st, lanes);
      double e = 0;
      for (int y = 0; y < st.h; ++y)
        for (int x = 0; x < st.w; ++x) {
          const uint8_t* gt = &target.data[(size_t(st.y0 + y) * target.width + st.x0 + x) * ch];
          for (int c = 0; c < 3; ++c) {
            const size_t k = (size_t(st.y0 + y) * f.width + st.x0 + x) * 3 + c;
            drawn.data[k] = st.C[c][y * kTile + x];
            photo.data[k] = float(gt[c]) * (1.f / 255.f);
            const float diff = drawn.data[k] - photo.data[k];
            e += double(diff) * diff;
          }
        }
      err[size_t(wk)] += e;
    });
    ImageF dssim;
    ssim_and_gradient(drawn, photo, &dssim, threads);
    for_tiles(f, threads, [&](int tile, int wk) {
      TileState& st = states[size_t(tile)];
      alignas(32) float dC[4 * kPixels] = {};
      depth_error(st, dC, wk);
      for (int y = 0; y < st.h; ++y)
        for (int x = 0; x < st.w; ++x) {
          const size_t k0 = (size_t(st.y0 + y) * f.width + st.x0 + x) * 3;
          for (int c = 0; c < 3; ++c)
            dC[c * kPixels + y * kTile + x] =
                (1.f - ssim_weight) * scale * colour_slope(drawn.data[k0 + c] - photo.data[k0 + c]) - ssim_weight * dssim.data[k0 + c];
        }
      tile_backward(f, tile, bg, st, dC, (*grads_out)[size_t(wk)].data(), lanes);
    });
    depth_totals();
    return std::accumulate(err.begin(), err.end(), 0.0);
  }
  for_tiles(f, threads, [&](int tile, int wk) {
    TileState st;
    tile_forward(f, tile, bg, st, lanes);
    alignas(32) float dC[4 * kPixels];
    err[size_t(wk)] += squared_error(st, dC);
    depth_error(st, dC, wk);
    if (grads_out) tile_backward(f, tile, bg, st, dC, (*grads_out)[size_t(wk)].data(), lanes);
  });
  depth_totals();
  return std::accumulate(err.begin(), err.end(), 0.0);
}

}  // namespace fit_detail

namespace {

using fit_detail::forward_backward;
using fit_detail::project;

// Box-filtered by s; a single-channel image stays one channel, any other
// becomes RGB (its first three).
ImageU8 downscale(const ImageU8& im, int s) {
  const int ch = im.channels == 1 ? 1 : 3;
  if (s == 1 && im.channels == ch) return im;
  ImageU8 out(im.width / s, im.height / s, ch);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x)
      for (int c = 0; c < ch; ++c) {
        int sum = 0;
        for (int dy = 0; dy < s; ++dy)
          for (int dx = 0; dx < s; ++dx) sum += im.at(x * s + dx, y * s + dy, std::min(c, im.channels - 1));
        out.at(x, y, c) = uint8_t((sum + s * s / 2) / (s * s));
      }
  return out;
}

// A depth image box-filtered by s: a block's mean where every pixel of it
// has a depth, else 0 (none: a block across the silhouette mixes the
// object's distance with what lies behind it).
ImageF downscale_depth(const ImageF& im, int s) {
  ImageF out(im.width / s, im.height / s, 1);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) {
      float sum = 0;
      bool whole = true;
      for (int dy = 0; dy < s && whole; ++dy)
        for (int dx = 0; dx < s; ++dx) {
          const float d = im.at(x * s + dx, y * s + dy);
          if (!(d > 0)) {
            whole = false;
            break;
          }
          sum += d;
        }
      out.at(x, y) = whole ? sum / float(s * s) : 0.f;
    }
  return out;
}

// The parameters of one splat as a flat vector (the optimiser's view).
int param_count(int coeffs) { return 5 + 3 * coeffs; }
void gather(const Splat& s, int coeffs, float* out) {
  out[0] = s.offset.x(), out[1] = s.offset.y(), out[2] = s.offset.z();
  out[3] = s.log_sigma, out[4] = s.opacity_logit;
  for (int k = 0; k < 3 * coeffs; ++k) out[5 + k] = s.sh[size_t(k)];
}
void scatter(const float* in, int coeffs, Splat& s) {
  const float h = 0.5f * s.voxel;
  s.offset = Eigen::Vector3f(std::clamp(in[0], -h, h), std::clamp(in[1], -h, h), std::clamp(in[2], -h, h));
  s.log_sigma = std::clamp(in[3], std::log(0.05f * s.voxel), std::log(4.f * s.voxel));
  s.opacity_logit = std::clamp(in[4], -12.f, 12.f);
  for (int k = 0; k < 3 * coeffs; ++k) s.sh[size_t(k)] = in[5 + k];
}

}  // namespace

// Each child sits in its own half-size sub-cell, as near as that allows to
// the parent's centre moved by d = (sqrt 3 / 2) sigma along each axis
// towards the sub-cell, and has footprint sigma / 2: along any direction the
// eight together then spread as the parent did (sigma^2 / 4 + d^2 =
// sigma^2). Each child's opacity is 1 - sqrt(1 - o): two of them behind each
// other give the parent's o. Measured on a fitted sphere: the children draw
// the parents' image at 40 dB (at the sub-cell centres with the parent's
// offset and sigma / 2: 34 dB); on lego, at equal epochs, the fit ends the
// same either way (28.64 against 28.65 dB on 20 val views).
std::vector<Splat> split_splats(const std::vector<Splat>& in) {
  std::vector<Splat> out;
  out.reserve(in.size() * 8);
  for (const Splat& s : in) {
    const float wc = 0.5f * s.voxel, q = 0.5f * wc;
    const Eigen::Vector3f c = s.centre();
    const float sigma = s.sigma(), d = 0.5f * std::sqrt(3.f) * sigma;
    const float o = 1.f - std::sqrt(1.f - std::min(s.opacity(), 0.99f));
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3f sk((k & 1) ? 1.f : -1.f, (k & 2) ? 1.f : -1.f, (k & 4) ? 1.f : -1.f);
      Splat ch = s;
      ch.voxel = wc;
      ch.anchor = s.anchor + q * sk;
      ch.offset = (c + d * sk - ch.anchor).cwiseMax(-0.5f * wc).cwiseMin(0.5f * wc);
      ch.log_sigma = std::clamp(std::log(0.5f * sigma), std::log(0.05f * wc), std::log(4.f * wc));
      ch.opacity_logit = logit(std::clamp(o, 1e-4f, 0.99f));
      out.push_back(ch);
    }
  }
  return out;
}

namespace {

// Facets of one grid merged into cells 2^levels voxels wide: a cell holds a
// facet where any of its voxels did, its colour their mean. The cells'
// children under split_splats() are the original voxels again.
std::vector<Splat> merge_cells(const std::vector<Splat>& in, int levels, const SplatFitOptions& o) {
  const float w = in.front().voxel;
  const int n = 1 << levels;
  std::map<std::array<int, 3>, std::pair<Splat, int>> cells;
  for (const Splat& s : in) {
    std::array<int, 3> c;
    for (int a = 0; a < 3; ++a) c[size_t(a)] = int(std::floor(std::lround(s.anchor[a] / w) / double(n)));
    auto [it, fresh] = cells.try_emplace(c, s, 0);
    if (!fresh)
      for (int k = 0; k < 3; ++k) it->second.first.sh[size_t(k)] += s.sh[size_t(k)];
    ++it->second.second;
  }
  std::vector<Splat> out;
  out.reserve(cells.size());
  for (auto& [c, sc] : cells) {
    Splat s = sc.first;
    for (int k = 0; k < 3; ++k) s.sh[size_t(k)] /= float(sc.second);
    s.voxel = w * float(n);
    for (int a = 0; a < 3; ++a) s.anchor[a] = (float(c[size_t(a)] * n) + 0.5f * float(n - 1)) * w;
    s.offset.setZero();
    s.log_sigma = std::log(float(o.sigma_init) * s.voxel);
    out.push_back(s);
  }
  return out;
}

bool finite(const Splat& s, int coeffs) {
  if (!s.offset.allFinite() || !std::isfinite(s.log_sigma) || !std::isfinite(s.opacity_logit)) return false;
  for (int k = 0; k < 3 * coeffs; ++k)
    if (!std::isfinite(s.sh[size_t(k)])) return false;
  return true;
}

}  // namespace

std::string DivergenceGuard::observe(int epoch, int scale, double psnr, bool whole) {
  if (!whole)
    return std::isfinite(psnr) ? std::string() : fmt::format("fit: diverged: training error not finite at epoch {}", epoch);
  auto it = std::find_if(best_.begin(), best_.end(), [&](const auto& b) { return b.first == scale; });
  if (it == best_.end()) it = best_.insert(best_.end(), {scale, psnr});
  it->second = std::max(it->second, psnr);
  // Under half an 8-bit level of error is as good as the photos can say
  // (a photo that is already drawn exactly starts at the 120-dB cap).
  if (psnr >= kQuantizationPsnrDb) return {};
  if (!(psnr >= it->second - 3) || (stage_ == 0 && scale == initial_scale_ && !(psnr >= initial_ - 0.5)))
    return fmt::format("fit: diverged: training PSNR {:.1f} dB at epoch {} (at the start {:.1f} dB, the best at this "
                       "scale in this stage {:.1f} dB)",
                       psnr, epoch, initial_, it->second);
  return {};
}

void sh_basis(const Eigen::Vector3f& d, int n, float* out) {
  out[0] = kC0;
  if (n < 4) return;
  const float x = d.x(), y = d.y(), z = d.z();
  out[1] = -kC1 * y, out[2] = kC1 * z, out[3] = -kC1 * x;
  if (n < 9) return;
  out[4] = kC2[0] * x * y;
  out[5] = kC2[1] * y * z;
  out[6] = kC2[2] * (2 * z * z - x * x - y * y);
  out[7] = kC2[3] * x * z;
  out[8] = kC2[4] * (x * x - y * y);
}

Eigen::Vector3f splat_color(const Splat& s, int coeffs, const Eigen::Vector3f& dir) {
  float b[kMaxShCoeffs];
  sh_basis(dir, coeffs, b);
  Eigen::Vector3f c = Eigen::Vector3f::Constant(0.5f);
  for (int k = 0; k < coeffs; ++k)
    for (int ch = 0; ch < 3; ++ch) c[ch] += s.sh[size_t(k * 3 + ch)] * b[k];
  return c.cwiseMax(0.f);
}

ImageF render_splats(const std::vector<Splat>& splats, int coeffs, const Intrinsics& K,
                     const Eigen::Isometry3d& world_from_camera, const std::array<float, 3>& background, ImageF* alpha_out,
                     int threads, float pixel_filter_px2) {
  const SplatFrame f = project(splats, coeffs, K, world_from_camera, threads, pixel_filter_px2);
  ImageF out(K.width, K.height, 3);
  if (alpha_out) *alpha_out = ImageF(K.width, K.height, 1);
  for_tiles(f, threads, [&](int tile, int) {
    TileState st;
    fit_detail::tile_forward(f, tile, Behind{background.data()}, st);
    for (int y = 0; y < st.h; ++y)
      for (int x = 0; x < st.w; ++x) {
        for (int c = 0; c < 3; ++c) out.at(st.x0 + x, st.y0 + y, c) = st.C[c][y * kTile + x];
        if (alpha_out) alpha_out->at(st.x0 + x, st.y0 + y) = 1.f - st.T[y * kTile + x];
      }
  });
  return out;
}

Status SplatFitOptions::validate() const {
  if (!(seconds > 0) && max_epochs <= 0) return fail(ErrorCode::invalid, "fit: seconds: must be > 0 (or max_epochs set)");
  if (sh_degree < 0 || sh_degree > 2) return fail(ErrorCode::invalid, "fit: sh_degree: must be 0, 1 or 2");
  if (!(sigma_init > 0)) return fail(ErrorCode::invalid, "fit: sigma_init: must be > 0");
  if (!(opacity_init > 0 && opacity_init < 1)) return fail(ErrorCode::invalid, "fit: opacity_init: must be in (0, 1)");
  for (double lr : {lr_color, lr_rest, lr_opacity, lr_sigma, lr_offset})
    if (!(lr >= 0) || !std::isfinite(lr)) return fail(ErrorCode::invalid, "fit: learning rates must be >= 0 and finite");
  if (!(pixel_filter_px2 >= 0 && pixel_filter_px2 <= 4)) return fail(ErrorCode::invalid, "fit: pixel_filter_px2: must be in [0, 4] (pixels^2)");
  if (!(lr_final > 0 && lr_final <= 1)) return fail(ErrorCode::invalid, "fit: lr_final: must be in (0, 1]");
  if (!(stage_time_growth >= 0.25 && stage_time_growth <= 16))
    return fail(ErrorCode::invalid, "fit: stage_time_growth: must be in [0.25, 16]");
  if (coarse_levels < 0 || coarse_levels > 4) return fail(ErrorCode::invalid, "fit: coarse_levels: must be in 0..4");
  if (!(ssim_weight >= 0 && ssim_weight < 1)) return fail(ErrorCode::invalid, "fit: ssim_weight: must be in [0, 1)");
  if (!(depth_weight >= 0) || !std::isfinite(depth_weight)) return fail(ErrorCode::invalid, "fit: depth_weight: must be >= 0 and finite");
  for (float b : background)
    if (!(b >= 0 && b <= 1)) return fail(ErrorCode::invalid, "fit: background: each channel must be in [0, 1]");
  return {};
}

std::vector<Splat> init_splats(const std::vector<Eigen::Vector3f>& anchors, float voxel, const std::vector<SplatView>& views,
                               const SplatFitOptions& options) {
  std::vector<Splat> out(anchors.size());
  parallel_for(int(anchors.size() + 4095) / 4096, options.threads, [&](int chunk) {
    for (size_t i = size_t(chunk) * 4096; i < std::min(anchors.size(), size_t(chunk + 1) * 4096); ++i) {
      Splat& s = out[i];
      s.anchor = anchors[i];
      s.voxel = voxel;
      s.log_sigma = std::log(float(options.sigma_init) * voxel);
      s.opacity_logit = logit(float(options.opacity_init));
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      int n = 0;
      for (const auto& v : views) {
        const auto px = v.intrinsics.project(v.world_from_camera.inverse() * anchors[i].cast<double>());
        if (!px || !v.intrinsics.contains(*px)) continue;
        const int x = int(std::lround(px->x())), y = int(std::lround(px->y()));
        if (x < 0 || y < 0 || x >= v.photo->width || y >= v.photo->height) continue;
        for (int c = 0; c < 3; ++c) sum[c] += v.photo->at(x, y, std::min(c, v.photo->channels - 1)) / 255.0;
        ++n;
      }
      const Eigen::Vector3d mean = n ? Eigen::Vector3d(sum / n) : Eigen::Vector3d::Constant(0.5);
      for (int c = 0; c < 3; ++c) s.sh[size_t(c)] = float((mean[c] - 0.5) / kC0);
    }
  });
  return out;
}

Result<SplatFitSummary> fit_splats(std::vector<Splat>& splats_io, const std::vector<SplatView>& views,
                                   const SplatFitOptions& o) {
  if (auto st = o.validate(); !st) return std::unexpected(st.error());
  if (views.empty()) return fail(ErrorCode::invalid, "fit: no training photos");
  if (splats_io.empty()) return fail(ErrorCode::invalid, "fit: no facets to fit");
  for (const auto& v : views)
    if (!v.photo || v.photo->width != v.intrinsics.width || v.photo->height != v.intrinsics.height)
      return fail(ErrorCode::invalid, "fit: a photo's size differs from its camera's");
  for (const auto& v : views)
    if (v.backdrop && (v.backdrop->width != v.photo->width || v.backdrop->height != v.photo->height || v.backdrop->channels < 3))
      return fail(ErrorCode::invalid, "fit: a backdrop plate's size differs from its photo's (or it is not RGB)");
  for (const auto& v : views)
    if (v.matte && (v.matte->width != v.photo->width || v.matte->height != v.photo->height || v.matte->channels != 1))
      return fail(ErrorCode::invalid, "fit: a matte's size differs from its photo's (or it is not one channel)");
  for (const auto& v : views)
    if (v.depth && (v.depth->width != v.photo->width || v.depth->height != v.photo->height || v.depth->channels != 1))
      return fail(ErrorCode::invalid, "fit: a depth image's size differs from its photo's (or it is not one channel)");
  using clock = std::chrono::steady_clock;
  const auto t0 = clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(clock::now() - t0).count(); };
  const int coeffs = sh_coeffs(o.sh_degree);
  const float filter = float(o.pixel_filter_px2);
  const int np = param_count(coeffs);
  std::vector<Splat> splats = splats_io;
  SplatFitSummary sum;
  sum.initial = splats.size();
  // The pyramid's levels of the photos (and of the mattes), built once when
  // first used; at full scale the caller's own images where they need no
  // conversion, not copies (a 200-photo capture at 12 MP is 7 GB of photos).
  struct Level {
    std::vector<ImageU8> owned;
    std::vector<const ImageU8*> at;
  };
  auto make_level = [&](int s, auto image_of) {
    Level l{std::vector<ImageU8>(views.size()), std::vector<const ImageU8*>(views.size(), nullptr)};
    parallel_for(int(views.size()), o.threads, [&](int i) {
      const ImageU8* im = image_of(views[size_t(i)]);
      if (!im) return;
      const bool as_is = s == 1 && (im->channels == 1 || im->channels == 3);
      if (!as_is) l.owned[size_t(i)] = downscale(*im, s);
      l.at[size_t(i)] = as_is ? im : &l.owned[size_t(i)];
    });
    return l;
  };
  std::map<int, Level> pyramid;
  auto level = [&](int s) -> const std::vector<const ImageU8*>& {
    auto it = pyramid.find(s);
    if (it == pyramid.end()) it = pyramid.emplace(s, make_level(s, [](const SplatView& v) { return v.photo; })).first;
    return it->second.at;
  };
  // The views' backdrop plates at each scale (views usually share one).
  std::map<std::pair<const ImageU8*, int>, ImageU8> plates;
  for (const auto& vw : views)
    if (vw.backdrop) plates.try_emplace({vw.backdrop, 1}, *vw.backdrop);
  // The views' depth at each scale (a pixel's mean over its block where the
  // whole block has a depth, else none).
  const bool fit_depth = o.depth_weight > 0 && std::any_of(views.begin(), views.end(), [](const SplatView& v) { return v.depth; });
  std::map<int, std::vector<ImageF>> depth_pyramid;
  auto depth_level = [&](size_t i, int s) -> const ImageF* {
    if (!fit_depth || !views[i].depth) return nullptr;
    if (s == 1) return views[i].depth;  // the caller's own, not a copy
    auto it = depth_pyramid.find(s);
    if (it == depth_pyramid.end()) {
      std::vector<ImageF> l(views.size());
      parallel_for(int(views.size()), o.threads, [&](int k) {
        if (views[size_t(k)].depth) l[size_t(k)] = downscale_depth(*views[size_t(k)].depth, s);
      });
      it = depth_pyramid.emplace(s, std::move(l)).first;
    }
    return &it->second[i];
  };
  auto behind = [&](size_t i, int s) -> Behind {
    const ImageU8* b = views[i].backdrop;
    if (!b) return Behind{o.background.data(), nullptr, depth_level(i, s)};
    auto it = plates.find({b, s});
    if (it == plates.end()) it = plates.emplace(std::pair{b, s}, downscale(*b, s)).first;
    return Behind{o.background.data(), &it->second, depth_level(i, s)};
  };
  // Random backgrounds: the mattes at each scale, and a step's photo moved
  // onto colour r under its matte (into `moved`).
  std::map<int, Level> matte_pyramid;
  auto matte_level = [&](int s) -> const std::vector<const ImageU8*>& {
    auto it = matte_pyramid.find(s);
    if (it == matte_pyramid.end()) it = matte_pyramid.emplace(s, make_level(s, [](const SplatView& v) { return v.matte; })).first;
    return it->second.at;
  };
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  auto step_target = [&](size_t i, int s, const ImageU8& photo, std::mt19937& gen, std::array<float, 3>& colour,
                         ImageU8& moved) -> std::pair<const ImageU8*, Behind> {
    if (!o.random_background || !views[i].matte || views[i].backdrop) return {&photo, behind(i, s)};
    for (float& c : colour) c = unit(gen);
    const ImageU8& m = *matte_level(s)[i];
    moved = ImageU8(photo.width, photo.height, 3);
    float shift[3];
    for (int c = 0; c < 3; ++c) shift[c] = (colour[size_t(c)] - o.background[size_t(c)]) * 255.f;
    for (size_t p = 0; p < photo.pixels(); ++p) {
      const float open = 1.f - float(m.data[p]) * (1.f / 255.f);
      for (size_t c = 0; c < 3; ++c)
        moved.data[p * 3 + c] = uint8_t(std::clamp(std::lround(float(photo.data[p * size_t(photo.channels) + c]) + shift[c] * open), 0L, 255L));
    }
    return {&moved, Behind{colour.data(), nullptr, depth_level(i, s)}};
  };
  // Stages, coarse to fine: the grid starts 2^coarse_levels times coarser
  // than the facets given (their cells merged), each stage ends by halving
  // it (refine: once more below the given size). A stage's photos are at
  // the scale where its voxel spans about 1.5 pixels or more, the second
  // half of the stage at twice that resolution.
  const float w_in = splats.front().voxel;
  const fit_detail::Loss loss{float(o.ssim_weight), o.loss == SplatFitOptions::Loss::l1,
                              fit_depth ? float(o.depth_weight) / (w_in * w_in) : 0.f};
  if (o.coarse_levels > 0) splats = merge_cells(splats, o.coarse_levels, o);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const Splat& p : splats) centroid += p.anchor.cast<double>();
  centroid /= double(splats.size());
  std::vector<double> px_per_m;
  for (const auto& vw : views)
    px_per_m.push_back(vw.intrinsics.fx / std::max(1e-9, (vw.world_from_camera.inverse() * centroid).z()));
  std::nth_element(px_per_m.begin(), px_per_m.begin() + std::ptrdiff_t(px_per_m.size() / 2), px_per_m.end());
  const double focal_per_m = px_per_m[px_per_m.size() / 2];
  struct Stage {
    double from, to;        // fractions of the epochs (max_epochs)
    double t_from, t_to;    // fractions of the seconds
    int scale_first, scale_second;
  };
  std::vector<Stage> stages;
  {
    const int n = o.coarse_levels + 1 + (o.refine ? 1 : 0);
    // Where each stage ends, as a fraction of the whole, stage k weighing growth^k.
    auto shares = [n](double growth) {
      std::vector<double> to(static_cast<size_t>(n));
      double at = 0, weight = 1;
      for (double& t : to) t = at += weight, weight *= growth;
      for (double& t : to) t /= at;
      return to;
    };
    const std::vector<double> e_to = shares(1.5), t_to = shares(o.stage_time_growth);
    for (int k = 0; k < n; ++k) {
      const double w = w_in * std::ldexp(1.0, o.coarse_levels - k);
      int scale = 1;
      while (scale < 8 && w * focal_per_m / (2 * scale) >= 1.5) scale *= 2;
      stages.push_back({k ? e_to[size_t(k - 1)] : 0.0, e_to[size_t(k)], k ? t_to[size_t(k - 1)] : 0.0, t_to[size_t(k)],
                        scale, k + 1 == n ? 1 : std::max(1, scale / 2)});
    }
  }
  std::mt19937 rng(7);
  std::vector<float> m, v, used, pull, drawn_steps;
  long step = 0;
  int epoch = 0;
  std::vector<std::vector<Grad>> grads;
  SplatFrame f;  // each step's projection, its storage reused
  std::vector<int> order(views.size());
  std::iota(order.begin(), order.end(), 0);
  size_t next_mark = 0;
  const double budget = o.seconds > 0 ? o.seconds : 1e300;
  auto take_snapshots = [&] {
    while (next_mark < o.seconds_marks.size() && elapsed() >= o.seconds_marks[next_mark])
      sum.snapshots.emplace_back(o.seconds_marks[next_mark++], splats);
  };
  // The error before any step, at the first scale: an epoch there that ends
  // worse than this has diverged.
  double initial_psnr = 0;
  {
    const int s0 = stages[0].scale_first;
    const auto& photos = level(s0);
    double sq = 0, px = 0, dsq = 0, dpx = 0;
    const size_t step_views = std::max<size_t>(1, views.size() / 8);  // eight views, evenly spaced
    std::mt19937 gen(11);
    for (size_t i = 0; i < views.size(); i += step_views) {
      const Intrinsics K = scaled(views[i].intrinsics, s0);
      std::array<float, 3> colour;
      ImageU8 moved;
      const auto [target, bg] = step_target(i, s0, *photos[i], gen, colour, moved);
      sq += forward_backward(project(splats, coeffs, K, views[i].world_from_camera, o.threads, filter), *target, bg, 1.f,
                             o.threads, nullptr, {}, 0, &dsq, &dpx);
      px += 3.0 * K.width * K.height;
    }
    initial_psnr = 10 * std::log10(1.0 / std::max(sq / px, 1e-12));
    sum.initial_depth_rms_m = dpx > 0 ? std::sqrt(dsq / dpx) : 0;
    sum.seconds_initial = elapsed();
    sum.initial_psnr_db = initial_psnr;
  }
  DivergenceGuard guard(initial_psnr, stages[0].scale_first);
  int stage_epochs = 0;             // whole passes over the photos in the stage
  for (size_t si = 0; si < stages.size(); ++si) {
    const Stage& st = stages[si];
    if (si > 0) guard.new_stage();
    if (si > 0 && stage_epochs > 0) {
      // Refinement: drop what the photos do not need (nearly transparent, or
      // under one pixel's weight per pass over the photos: hidden inside),
      // split the rest up to max_facets: first those the photos pull hardest
      // (the mean gradient of their image position) or the most used.
      const bool by_gradient = o.split_by == SplatFitOptions::SplitBy::gradient;
      std::vector<std::pair<float, size_t>> keep;
      for (size_t i = 0; i < splats.size(); ++i)
        if (splats[i].opacity() >= o.prune_opacity && used[i] >= stage_epochs)
          keep.push_back({by_gradient ? -pull[i] / std::max(1.f, drawn_steps[i]) : -used[i], i});
      std::sort(keep.begin(), keep.end());
      sum.pruned += splats.size() - keep.size();
      sum.refined_from = keep.size();
      // Before the last stage, half the cap: the finest grid gets the facets.
      const size_t cap = si + 1 == stages.size() ? o.max_facets : o.max_facets / 2;
      const size_t splits = std::min(keep.size(), cap > keep.size() ? (cap - keep.size()) / 7 : 0);
      std::vector<Splat> parents, whole;
      for (size_t k = 0; k < keep.size(); ++k) (k < splits ? parents : whole).push_back(splats[keep[k].second]);
      sum.split = splits;
      splats = split_splats(parents);
      splats.insert(splats.end(), whole.begin(), whole.end());
    }
    // Along a Morton curve: the facets of one screen tile lie near each other
    // in memory, as the passes and the step read them.
    if (const auto ord = morton_order(splats.size(), [&](size_t i) { return splats[i].centre(); }); !ord.empty()) {
      std::vector<Splat> sorted;
      sorted.reserve(splats.size());
      for (uint32_t i : ord) sorted.push_back(splats[i]);
      splats.swap(sorted);
    }
    m.assign(splats.size() * size_t(np), 0.f);
    v.assign(splats.size() * size_t(np), 0.f);
    used.assign(splats.size(), 0.f);
    pull.assign(splats.size(), 0.f);
    drawn_steps.assign(splats.size(), 0.f);
    long stage_steps = 0;
    stage_epochs = 0;
    const double stage_start = elapsed();
    const double stage_end = st.t_to * budget;
    const int epoch_cap = o.max_epochs > 0 ? std::max(1, int(std::lround(o.max_epochs * (st.to - st.from)))) : 1 << 30;
    for (int e = 0; e < epoch_cap; ++e) {
      const double t_now = elapsed();
      if (t_now >= stage_end) break;
      const double frac_epochs = o.max_epochs > 0 ? double(e) / epoch_cap : 0;
      const double frac_time = (t_now - stage_start) / std::max(1e-9, stage_end - stage_start);
      const int scale = std::max(frac_epochs, frac_time) < 0.5 ? st.scale_first : st.scale_second;
      const auto& photos = level(scale);
      std::shuffle(order.begin(), order.end(), rng);
      double sq = 0, px = 0, dsq = 0, dpx = 0;
      int done = 0;
      for (int vi : order) {
        const double t = elapsed();
        if (t >= stage_end) break;
        const double frac = std::clamp(std::max(o.max_epochs > 0 ? (e + double(done) / views.size()) / epoch_cap : 0.0,
                                                (t - stage_start) / std::max(1e-9, stage_end - stage_start)),
                                       0.0, 1.0);
        const float lr_scale = float(std::pow(o.lr_final, frac));
        const SplatView& view = views[size_t(vi)];
        const Intrinsics K = scaled(view.intrinsics, scale);
        std::array<float, 3> colour;
        ImageU8 moved;
        const auto [target, bg] = step_target(size_t(vi), scale, *photos[size_t(vi)], rng, colour, moved);
        const double t_a = elapsed();
        project_into(f, splats, coeffs, K, view.world_from_camera, o.threads, filter);
        const double t_b = elapsed();
        const float inv = 1.f / float(3.0 * K.width * K.height);
        sq += forward_backward(f, *target, bg, inv, o.threads, &grads, loss, 0, &dsq, &dpx);
        const double t_c = elapsed();
        sum.seconds_project += t_b - t_a;
        sum.seconds_raster += t_c - t_b;
        px += 3.0 * K.width * K.height;
        ++done;
        // Adam on the splats this photo sees.
        ++step, ++stage_steps;
        const float b1 = 0.9f, b2 = 0.999f, eps = 1e-8f;
        const float c1 = 1.f - std::pow(b1, float(stage_steps)), c2 = 1.f - std::pow(b2, float(stage_steps));
        const Eigen::Matrix3f R = view.world_from_camera.rotation().cast<float>();
        const Eigen::Vector3f eye = view.world_from_camera.translation().cast<float>();
        // The projected facets are in the facets' order: parameters, moments
        // and gradients are read in sequence.
        parallel_for(int(f.p.size() + 8191) / 8192, o.threads, [&](int chunk) {
          float basis[kMaxShCoeffs], p[5 + 3 * kMaxShCoeffs], g[5 + 3 * kMaxShCoeffs];
          const size_t end = std::min(f.p.size(), size_t(chunk + 1) * 8192);
          for (size_t i = size_t(chunk) * 8192; i < end; ++i) {
            Grad gr{};
            for (const auto& tg : grads) {
              const Grad& q = tg[i];
              for (int c = 0; c < 3; ++c) gr.c[c] += q.c[c];
              gr.o += q.o, gr.sigma += q.sigma, gr.u += q.u, gr.v += q.v, gr.weight += q.weight, gr.dist += q.dist;
            }
            if (gr.weight <= 0) continue;
            const Projected& pr = f.p[i];
            Splat& s = splats[pr.id];
            used[pr.id] += gr.weight;
            pull[pr.id] += std::hypot(gr.u, gr.v);
            drawn_steps[pr.id] += 1.f;
            // Chain rule to the parameters.
            const float z = pr.pc.z();
            // d loss / d log sigma_px, through the pixel filter's sigma and opacity.
            const float dlog = gr.sigma * pr.sigma_gain + gr.o * pr.opacity_gain_sigma;
            const float dz = -(gr.u * float(K.fx) * pr.pc.x() + gr.v * float(K.fy) * pr.pc.y()) / (z * z) - dlog / z;
            const Eigen::Vector3f dcam(gr.u * float(K.fx) / z, gr.v * float(K.fy) / z, dz);
            const Eigen::Vector3f dworld = R * (dcam + pr.pc * (gr.dist / pr.dist));
            g[0] = dworld.x(), g[1] = dworld.y(), g[2] = dworld.z();
            g[3] = dlog;
            const float o_facet = s.opacity();
            g[4] = gr.o * pr.opacity_gain * o_facet * (1.f - o_facet);
            sh_basis((s.centre() - eye).normalized(), coeffs, basis);
            for (int k = 0; k < coeffs; ++k)
              for (int c = 0; c < 3; ++c) g[5 + k * 3 + c] = (pr.clamped >> c & 1) ? 0.f : gr.c[c] * basis[k];
            gather(s, coeffs, p);
            float* mi = &m[size_t(pr.id) * np];
            float* vi2 = &v[size_t(pr.id) * np];
            for (int k = 0; k < np; ++k) {
              const float lr = k < 3 ? float(o.lr_offset) * s.voxel : k == 3 ? float(o.lr_sigma)
                             : k == 4 ? float(o.lr_opacity) : k < 8 ? float(o.lr_color) : float(o.lr_rest);
              mi[k] = b1 * mi[k] + (1 - b1) * g[k];
              vi2[k] = b2 * vi2[k] + (1 - b2) * g[k] * g[k];
              p[k] -= lr * lr_scale * (mi[k] / c1) / (std::sqrt(vi2[k] / c2) + eps);
            }
            scatter(p, coeffs, s);
          }
        });
        sum.seconds_update += elapsed() - t_c;
        if (!std::isfinite(sq)) return fail(ErrorCode::invalid, fmt::format("fit: diverged (error not finite) at step {}", step));
        take_snapshots();
        if (o.on_progress)
          o.on_progress(std::min(1.0, std::max(elapsed() / budget, o.max_epochs > 0 ? (epoch + double(done) / double(views.size())) / o.max_epochs : 0.0)));
      }
      if (done == 0) break;
      ++epoch;
      if (done == int(views.size())) ++stage_epochs;
      const double mse = sq / std::max(1.0, px);
      const double psnr = 10 * std::log10(1.0 / std::max(mse, 1e-12));
      sum.curve.push_back({elapsed(), epoch, scale, psnr, splats.size()});
      // The reported training error: the last whole pass over the photos at
      // full resolution (a pass cut short by the budget covers a few of them).
      const bool whole = done == int(views.size());
      if ((scale == 1 && whole) || sum.train_psnr_db == 0) {
        sum.train_psnr_db = psnr;
        if (dpx > 0) sum.depth_rms_m = std::sqrt(dsq / dpx);
      }
      if (const std::string bad = guard.observe(epoch, scale, psnr, whole); !bad.empty()) return fail(ErrorCode::invalid, bad);
    }
  }
  for (const Splat& s : splats)
    if (!finite(s, coeffs)) return fail(ErrorCode::invalid, "fit: diverged (a facet's parameters are not finite)");
  // The end: facets nearly transparent, or that no pixel used, are left out.
  std::vector<Splat> keep;
  keep.reserve(splats.size());
  for (size_t i = 0; i < splats.size(); ++i)
    if (splats[i].opacity() >= o.prune_opacity && used[i] > 0.f) keep.push_back(splats[i]);
  sum.pruned += splats.size() - keep.size();
  if (keep.empty()) return fail(ErrorCode::invalid, "fit: no facet left (every one transparent or unused by the photos)");
  sum.final_count = keep.size();
  sum.epochs = epoch;
  sum.steps = step;
  sum.seconds = elapsed();
  splats_io = std::move(keep);
  return sum;
}

}  // namespace s2r
