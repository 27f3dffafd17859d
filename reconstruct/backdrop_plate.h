// The backdrop plate: what a fixed camera sees behind the object. On a
// turntable the camera and the room stay put while the object turns, so the
// backdrop is the same image in every photo; it is not part of the object's
// world (it would turn with the table there) and no amount of geometry can
// draw it. The plate is the per-pixel median of the training photos where the
// model's geometry leaves the pixel empty; frames of the capture drawn from
// its cameras (held-out views, input views) show it behind the model.
// Pixels the object hides in nearly every photo (its holes) are filled from
// the plate around them by Telea's inpainting ("An Image Inpainting
// Technique Based on the Fast Marching Method", 2004; OpenCV's).
#pragma once

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "core/image.h"

namespace s2r {

struct BackdropPlateOptions {
  int margin_px = 3;          // a pixel counts as backdrop only this far from any geometry
  double min_share = 0.25;    // of the photos that must see a pixel as backdrop for it to be kept
  double max_spread = 12.0;   // static: the median over kept pixels of their samples' median absolute deviation (0..255)
  double uniform_tolerance = 4.0;  // uniform: the plate within this of the background (0..255) ...
  double uniform_share = 0.98;     // ... at this share of its pixels
  double fill_radius_px = 5;       // the inpainting's neighbourhood
};

struct BackdropPlateResult {
  std::optional<ImageU8> plate;  // RGB, the photos' size; empty: not needed or not static (see `skipped`)
  std::string skipped;           // why there is none: "views_differ_in_size", "not_static", "uniform", "no_backdrop_pixels"
  double kept_share = 0;         // of the pixels, those with enough backdrop samples
  double filled_share = 0;       // of the pixels, the holes filled from the plate around them
  double spread = 0;             // the static test's figure (0..255)
};

// `photos`: the training photos (RGB or more channels, the first three
// used), one camera's size; `empty[i]`: per pixel of photo i, non-zero where
// the model's geometry draws nothing. `background` (0..1) is what the
// uniform test compares with; pixels seen as backdrop in too few photos are
// filled from the plate around them.
BackdropPlateResult make_backdrop_plate(const std::vector<const ImageU8*>& photos, const std::vector<ImageU8>& empty,
                                        const std::array<float, 3>& background, const BackdropPlateOptions& options = {});

}  // namespace s2r
