#pragma once
// The fit's rasterizer (internal to reconstruct/): the projected facets of
// one image, each 16 x 16 tile composited front to back and then walked
// back to front for the loss's gradient (splat_fit.h has the image
// formation). A tile's loops run over a row's pixels 8 at a time (AVX2,
// where the processor has it) or 4; a scalar version of the same
// arithmetic is kept as the reference the tests hold the vector ones to.

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "reconstruct/model.h"

namespace s2r {
struct Splat;
}

namespace s2r::fit_detail {

inline constexpr int kTile = 16;

// One facet as one image sees it.
struct Projected {
  float u, v;         // centre, pixels
  float sigma;        // pixels
  float inv2s2;       // 1 / (2 sigma^2)
  float r2max;        // (3 sigma)^2: the cut
  float r2box;        // squared radius of the box a pass visits: the cut, or a hair past where alpha falls under 1/255 if nearer
  float o;            // opacity (after the pixel filter)
  // The pixel filter's chain rule (screen_footprint): d sigma / d log
  // sigma_px, d o / d log sigma_px and d o / d (the facet's opacity).
  float sigma_gain, opacity_gain_sigma, opacity_gain;
  float c[3];         // colour
  Eigen::Vector3f pc; // camera-frame centre
  float dist;         // |pc|: the centre's distance from the camera, the depth channel's value
  uint32_t id;        // facet index
  uint8_t clamped;    // bit per channel: the colour was clamped at 0
};

// The projected facets of one image (ascending ids), and each tile's list
// of them (indices into `p`, near to far).
struct SplatFrame {
  int width = 0, height = 0, tiles_x = 0, tiles_y = 0;
  std::vector<Projected> p;
  std::vector<uint32_t> tile_start, tile_list;
  // project_into's working space, kept with the frame so that a fit's steps
  // reuse it (at 600,000 facets some 60 MB a step the allocator would
  // otherwise map and fault in afresh).
  struct Scratch {
    std::vector<std::vector<Projected>> part;
    std::vector<std::pair<uint32_t, uint32_t>> keys, keys_tmp;
    std::vector<std::array<uint16_t, 4>> span;
    std::vector<uint32_t> counts;
  } scratch;
};

// Per projected facet, what one thread's pixels owe it: the loss's
// derivatives by its colour, opacity, sigma, centre (on screen, and its
// distance from the camera where the depth channel is fitted), and the
// summed compositing weight of the pixels it reached.
struct Grad {
  float c[3], o, sigma, u, v, weight, dist;
};

// What lies behind the facets: one colour, or per pixel a plate (RGB, the
// image's size) where the view has one.
// With `depth` (the image's size, 1 channel), the depth channel: per pixel
// the distance along its ray to the surface the facets should lie on (0:
// none there). The facets composite their distance |pc| as a fourth
// channel over that same distance behind them, so a pixel's depth error is
// sum_i (|pc_i| - d) w_i: opacity off the surface costs, opacity the
// colour does not ask for is not asked for.
struct Behind {
  const float* colour;
  const ImageU8* plate = nullptr;
  const ImageF* depth = nullptr;
  float at(int x, int y, int c) const { return plate ? float(plate->at(x, y, c)) * (1.f / 255.f) : colour[c]; }
  float depth_at(int x, int y) const { return depth ? depth->data[size_t(y) * depth->width + x] : 0.f; }
};

// One tile as tile_forward leaves it for tile_backward. Pixel (x, y) of the
// tile is entry y * kTile + x whatever the tile's width; colour planar.
struct TileState {
  int x0 = 0, y0 = 0, w = 0, h = 0;
  alignas(32) float T[kTile * kTile];      // transmittance left
  alignas(32) float C[4][kTile * kTile];   // colour, the background included; [3]: the depth channel (with bg.depth)
  alignas(32) int32_t end[kTile * kTile];  // list entries [lo, end) were composited
  alignas(32) int32_t done[kTile * kTile]; // 0, or -1 once opaque (and past the image's edge)
};

// The lanes the rasterizer uses: 8 where the processor has AVX2, else 4.
int widest_lanes();

// Composites the tile's list into `st` (`lanes`: 1, the scalar reference;
// 4; 8; 0: widest_lanes()).
void tile_forward(const SplatFrame& f, int tile, const Behind& bg, TileState& st, int lanes = 0);

// Back to front through the tile as tile_forward left it, the loss's
// derivative by each pixel's colour in `dC` (planar, 3 x kTile^2, the
// tile's layout; with bg.depth a fourth plane, the derivative by the
// pixel's depth channel), added into G (per projected facet). Consumes st.T.
void tile_backward(const SplatFrame& f, int tile, const Behind& bg, TileState& st, const float* dC, Grad* G,
                   int lanes = 0);

// The facets in front of the camera whose footprints reach the image, in
// id order, and each tile's list of them near to far (defined in
// splat_fit.cpp).
SplatFrame project(const std::vector<Splat>& splats, int coeffs, const Intrinsics& K,
                   const Eigen::Isometry3d& world_from_camera, int threads, float pixel_filter_px2 = kSplatPixelFilterPx2);
// The same into `f`, reusing its storage.
void project_into(SplatFrame& f, const std::vector<Splat>& splats, int coeffs, const Intrinsics& K,
                  const Eigen::Isometry3d& world_from_camera, int threads, float pixel_filter_px2 = kSplatPixelFilterPx2);

// The loss a step differentiates (forward_backward).
struct Loss {
  float ssim_weight = 0;  // w: (1 - w) x the colour term + w x (1 - SSIM)
  bool l1 = false;        // the colour term: the absolute error, else the squared error
  float depth_scale = 0;  // with bg.depth: plus this x the squared depth error
};

// The squared error of one image and, into `grads_out` (per thread, per
// projected facet; null: the error only), the gradient of the loss: `scale`
// x the colour term (the squared error, or with loss.l1 the absolute error,
// summed over pixels and channels), or with loss.ssim_weight w > 0, (1 - w)
// x that + w x (1 - SSIM) (the mean of the SSIM map, core/image_metrics.h;
// all tiles composited first, the map needing each pixel's neighbours).
// With bg.depth, plus loss.depth_scale x the squared depth error where the
// pixel has a depth (its sum added into `depth_sq`, the pixels counted into
// `depth_px`). `lanes` as tile_forward's.
double forward_backward(const SplatFrame& f, const ImageU8& target, const Behind& bg, float scale, int threads,
                        std::vector<std::vector<Grad>>* grads_out, const Loss& loss = {}, int lanes = 0,
                        double* depth_sq = nullptr, double* depth_px = nullptr);

}  // namespace s2r::fit_detail
