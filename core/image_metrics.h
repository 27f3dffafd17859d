// Image error metrics used by every evaluation: PSNR and SSIM, optionally
// restricted to a mask (e.g. the object's pixels).
//
// Both take 8-bit images of the same shape. Colour images are compared per
// channel and averaged. SSIM follows Wang et al. 2004: 11x11 Gaussian window,
// sigma 1.5, K1 = 0.01, K2 = 0.03, L = 255; the masked SSIM averages the SSIM
// map over mask pixels.
#pragma once

#include "core/image.h"
#include "core/result.h"

namespace s2r {

// Mask: single channel, non-zero = use the pixel. Pass nullptr for all pixels.
// Identical images give +infinity PSNR.
Result<double> psnr(const ImageU8& a, const ImageU8& b, const ImageU8* mask = nullptr);
// Where PSNRs are averaged over frames and written to reports, identical
// images count as 120 dB (a mean squared error of 1e-12 on a 0..1 scale, the
// fit's own cap), so a mean and its JSON stay numbers.
inline constexpr double kPsnrIdenticalDb = 120.0;
inline double finite_psnr(double db) { return db < kPsnrIdenticalDb ? db : kPsnrIdenticalDb; }
Result<double> ssim(const ImageU8& a, const ImageU8& b, const ImageU8* mask = nullptr);

// SSIM as a loss, on float images in 0..1 of the same shape (C1 = 0.01^2,
// C2 = 0.03^2, the same window): the mean of the SSIM map over every pixel
// and channel, the window's statistics taken with zeros beyond the edge (a
// symmetric filter, so the gradient is exact: the same filter applied to
// the map's derivatives). With `d_dx`, the mean's gradient with respect to
// each value of `x` (resized to x's shape). Wang, Bovik, Sheikh and
// Simoncelli, "Image Quality Assessment: From Error Visibility to
// Structural Similarity" (2004); as a training loss, Kerbl et al., "3D
// Gaussian Splatting for Real-Time Radiance Field Rendering" (2023).
// `threads` (0: every usable core) share the window's filters and the
// per-pixel terms; the result is the same for any count.
double ssim_and_gradient(const ImageF& x, const ImageF& y, ImageF* d_dx = nullptr, int threads = 1);

// A silhouette's band: the pixels whose matte is fractional (1..254) or
// within `band_px` pixels (a square neighbourhood) of where the matte crosses
// one half. 255 in the band, 0 elsewhere; an empty band where the matte is
// all inside or all outside. `matte` is single-channel; band_px >= 0.
Result<ImageU8> matte_band(const ImageU8& matte, int band_px = 2);

// A drawing's coverage (its alpha, single channel) against a true fractional
// matte: the mean absolute difference in [0, 1] over every pixel, and over
// the silhouette's band (matte_band), where hard or haloed edges show.
// edge_mae is 0 with edge_pixels 0 when the band is empty.
struct MatteError {
  double mae = 0, edge_mae = 0;
  size_t edge_pixels = 0;
};
Result<MatteError> matte_error(const ImageU8& alpha, const ImageU8& matte, const ImageU8& band);

}  // namespace s2r
