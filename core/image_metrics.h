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
Result<double> ssim(const ImageU8& a, const ImageU8& b, const ImageU8* mask = nullptr);

}  // namespace s2r
