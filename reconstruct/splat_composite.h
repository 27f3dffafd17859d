// Fitted billboards composited on the CPU for display: the image formation
// of splat_fit.h (camera-facing Gaussian footprints, front to back, a pixel
// finished once its transmittance would fall under 1e-4) made fast for a
// viewer on a machine whose OpenGL is a software rasterizer. There the GL
// pass pays for every fragment of every footprint, hidden or not, and runs
// its vertex stage on one thread; compositing front to back stops at the
// first opaque layer and works a 16 x 16 tile's rows 16 pixels at a time.
//
// The result is premultiplied colour and transmittance per pixel, so that
// the caller lays it over whatever is already drawn (a backdrop, an
// environment): out = rgb + T * under.
#pragma once

#include <cstddef>
#include <functional>
#include <memory>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "reconstruct/model.h"

namespace s2r {

struct SplatCompositeStats {
  size_t facets = 0, drawn = 0;  // all, and those in front of the camera and in the image
  size_t tile_entries = 0;       // (facet, tile) pairs listed
  size_t tiles_finished_early = 0;  // tiles whose every pixel became opaque before their list ended
  int lanes = 4;                 // pixels a vector: 8 with AVX2, else 4
  double ms_project = 0, ms_sort = 0, ms_composite = 0;
};

// `records`: the model's splats.bin (5 + 3 coeffs floats a facet: centre,
// sigma, opacity, SH coefficient-major). `rgba_out` becomes K.width x
// K.height x 4 floats, rows top to bottom: premultiplied RGB and T.
// Facets nearer than `near_m` are left out. A compositor keeps its buffers
// from frame to frame (a viewer draws many); composite_splats is one frame.
class SplatCompositor {
 public:
  SplatCompositor();
  ~SplatCompositor();
  SplatCompositor(SplatCompositor&&) noexcept;
  SplatCompositor& operator=(SplatCompositor&&) noexcept;

  void composite(const std::vector<float>& records, int coeffs, const Intrinsics& K, const Eigen::Isometry3d& world_from_camera,
                 double near_m, std::vector<float>& rgba_out, int threads = 0, SplatCompositeStats* stats = nullptr);
  // 4: four pixels a vector even where AVX2 would give eight (tests of
  // both); 0 (default): the widest the processor has.
  void set_lanes(int lanes) { lanes_ = lanes; }
  // The image formation's pixel filter, pixels^2 (the model's
  // SplatLayout::pixel_filter_px2; splat_fit.h).
  void set_pixel_filter(float px2) { pixel_filter_px2_ = px2; }

 private:
  struct Buffers;
  std::unique_ptr<Buffers> b_;
  int lanes_ = 0;
  float pixel_filter_px2_ = kSplatPixelFilterPx2;
};

// Reorders the facets (records of `stride` floats) along a Morton curve of
// their centres, so that the facets of one screen tile lie near each other
// in memory; the image formation does not depend on the order (depth ties
// aside). Returns false when they were already in that order.
bool order_splats_spatially(std::vector<float>& records, int stride);

// The order of n points (point(i)) along a Morton curve in their bounding
// box; empty when they are already in it.
std::vector<uint32_t> morton_order(size_t n, const std::function<Eigen::Vector3f(size_t)>& point);

void composite_splats(const std::vector<float>& records, int coeffs, const Intrinsics& K,
                      const Eigen::Isometry3d& world_from_camera, double near_m, std::vector<float>& rgba_out, int threads = 0,
                      SplatCompositeStats* stats = nullptr, float pixel_filter_px2 = kSplatPixelFilterPx2);

}  // namespace s2r
