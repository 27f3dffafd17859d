// Fitted billboards: each voxel-anchored facet gets an opacity, a footprint,
// an offset within its voxel and a view-dependent colour (real spherical
// harmonics of degree 0-2), fitted to the training photos by differentiable
// rasterization, as Kerbl, Kopanas, Leimkuehler and Drettakis fit their
// splats ("3D Gaussian Splatting for Real-Time Radiance Field Rendering",
// 2023), coarse to fine over a sparse voxel grid as Fridovich-Keil, Yu et al.
// do without a network ("Plenoxels: Radiance Fields without Neural Networks",
// 2022).
//
// Image formation (the same in the fit and in render/'s splat pass): facet i
// is a camera-facing billboard through its centre X_i whose footprint on
// screen is an isotropic Gaussian, sigma_px = sigma_i f / z_i (f = fx, z_i
// the centre's depth), centred on the projection of X_i through the camera's
// lens model, cut at 3 sigma. Its alpha at a pixel is min(0.99, o_i g),
// g the Gaussian; alpha under 1/255 draws nothing. The footprint is first
// convolved with a Gaussian of variance f = the pixel filter (pixels^2,
// about a pixel's box; kSplatPixelFilterPx2), its energy kept, as the 2D Mip
// filter of Yu, Chen, Huang, Sattler and Geiger ("Mip-Splatting: Alias-free
// 3D Gaussian Splatting", 2024): sigma'^2 = sigma_px^2 + f and
// o' = o sigma_px^2 / sigma'^2. A facet smaller than a pixel then draws as
// its share of the pixel instead of a point sampled at pixel centres, which
// shows as speckle in views between the photos (screen_footprint). The facets are composited
// front to back in order of z_i over the background b:
//     C = sum_i c_i alpha_i T_i + T_N b,  T_i = prod_{j<i} (1 - alpha_j),
// and a pixel stops once T would fall under 1e-4. c_i = max(0, 0.5 + SH(d)),
// d the unit direction from the camera's centre to X_i.
//
// The fit minimises the mean error of C against each training photo,
// squared or absolute (SplatFitOptions::loss), with SSIM beside it
// (composited on b where it has a matte) with Adam, one photo per step, on
// an image pyramid, coarse to fine over the grid as well: the fit starts on
// cells 2^coarse_levels voxels wide, and at the end of each stage facets
// whose opacity stays low or that the photos hardly use are dropped and the
// rest (the most used first, up to max_facets) split into their eight
// half-size children. Only training photos are
// read; the fit stops with an error, and writes nothing, when it diverges.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/result.h"
#include "reconstruct/model.h"

namespace s2r {

inline constexpr int kMaxShCoeffs = 9;  // degree 2
// The image formation's limits (the fit, the display compositor and the GL
// pass alike): alpha under the first draws nothing, alpha is capped at the
// second, and a pixel is finished once its transmittance would fall under
// the third.
inline constexpr float kSplatAlphaMin = 1.f / 255.f, kSplatAlphaMax = 0.99f, kSplatStopT = 1e-4f;

// One fitted facet (the model's splats.bin record is this, 60 + 4 * 27 bytes).
struct Splat {
  Eigen::Vector3f anchor = Eigen::Vector3f::Zero();  // voxel centre
  Eigen::Vector3f offset = Eigen::Vector3f::Zero();  // |offset|_inf <= voxel / 2
  float voxel = 0;          // w
  float log_sigma = 0;      // footprint sigma (metres) = exp(log_sigma)
  float opacity_logit = 0;  // opacity = sigmoid
  std::array<float, 3 * kMaxShCoeffs> sh{};  // per channel, coefficient-major: sh[k * 3 + c]
  Eigen::Vector3f centre() const { return anchor + offset; }
  float sigma() const { return std::exp(log_sigma); }
  float opacity() const { return 1.f / (1.f + std::exp(-opacity_logit)); }
};

// A facet's footprint on screen through the pixel filter (see the image
// formation above): its sigma' and o', and what the fit's chain rule needs,
// d sigma' / d log sigma_px, d o' / d log sigma_px and d o' / d o.
struct ScreenFootprint {
  float sigma, opacity;
  float sigma_gain, opacity_gain_sigma, opacity_gain;
};
inline ScreenFootprint screen_footprint(float sigma_px, float opacity, float filter_px2) {
  const float s2 = sigma_px * sigma_px, v = s2 + filter_px2;
  if (!(v > 0)) return {0.f, opacity, 0.f, 0.f, 1.f};
  const float keep = s2 / v, sigma = std::sqrt(v);
  return {sigma, opacity * keep, s2 / sigma, opacity * 2.f * s2 * filter_px2 / (v * v), keep};
}

// The squared radius (pixels) of the box a footprint of `sigma` pixels and
// opacity `opacity` (after the pixel filter) can draw in: the 3-sigma cut,
// or a hair past where its alpha falls under 1/255 if that is nearer (the
// alpha test, with the same exp, decides the edge pixels). The fit's passes
// and the CPU compositor visit only that box and list its tiles.
inline float splat_box_r2(float sigma, float opacity) {
  return sigma * sigma * std::min(9.f, 2.f * std::log(std::max(255.f * opacity, 1.f)) + 1e-3f);
}

// Whether a footprint centred at (u, v) whose box has squared radius `r2`
// reaches a pixel centre of tile (tx, ty), `tile` pixels square (pixel x's
// centre at x): a tile its box's corner overlaps but its disc does not is
// left out of the tile lists (no pixel there passes the alpha test). Only
// tiles off both the centre's tile row and column can be missed.
inline bool splat_reaches_tile(float u, float v, float r2, int tx, int ty, int tile) {
  const float x = std::clamp(u, float(tx * tile), float(tx * tile + tile - 1)) - u;
  const float y = std::clamp(v, float(ty * tile), float(ty * tile + tile - 1)) - v;
  return x * x + y * y <= r2;
}

// Real spherical-harmonic basis (the order and signs 3DGS uses), `n` = 1, 4 or 9.
void sh_basis(const Eigen::Vector3f& dir, int n, float* out);
// c = max(0, 0.5 + sum_k sh[k] basis[k]) per channel.
Eigen::Vector3f splat_color(const Splat& s, int coeffs, const Eigen::Vector3f& dir);
inline int sh_coeffs(int degree) { return (degree + 1) * (degree + 1); }

// LSD radix sort of (key, index) pairs by key (a positive float's bits sort
// as the float): the facets' depth order, per photo in the fit and per frame
// in the renderer.
void radix_sort(std::vector<std::pair<uint32_t, uint32_t>>& pairs,
                std::vector<std::pair<uint32_t, uint32_t>>* scratch = nullptr);

// The fit's divergence test, epoch by epoch: an epoch's training PSNR more
// than 0.5 dB under the error before any step (the first stage, at the scale
// that error was measured at: an epoch of one step is that error, summed
// over the tiles in another order), or more than 3 dB under
// the best epoch of the same stage at the same scale (an epoch's figure mixes
// the steps' states, so 3 dB). A new stage starts its own record: a stage
// begins with its facets just split, a few dB under where the last one
// ended, and that is not divergence.
// An epoch over the 8-bit quantisation's PSNR (rms error of a uniform half
// level, 10 log10(12 * 255^2) = 58.9 dB) is never divergence.
inline constexpr double kQuantizationPsnrDb = 58.9;
class DivergenceGuard {
 public:
  DivergenceGuard(double initial_psnr_db, int initial_scale) : initial_(initial_psnr_db), initial_scale_(initial_scale) {}
  void new_stage() { best_.clear(), ++stage_; }
  // An error message when `psnr_db` at `scale` is divergence, else empty.
  // An epoch cut short (`whole` false: a stage or the budget ended inside
  // it) is the error of the few photos it reached, not comparable with a
  // whole pass over them (on the Middlebury dino one photo can be 3 dB
  // under the mean): it neither counts nor sets a record, unless it is not
  // a number at all.
  std::string observe(int epoch, int scale, double psnr_db, bool whole = true);

 private:
  double initial_;
  int initial_scale_, stage_ = 0;
  std::vector<std::pair<int, double>> best_;  // (scale, best PSNR) in this stage
};

struct SplatView {
  Intrinsics intrinsics;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  const ImageU8* photo = nullptr;  // RGB (or more channels, the first three used), composited on the background
  // What lies behind the object in this photo, per pixel (RGB, the photo's
  // size: the backdrop plate), instead of the one background colour.
  const ImageU8* backdrop = nullptr;
  // The object's fractional matte (1 channel, the photo's size) under which
  // the photo was composited on the background; with
  // SplatFitOptions::random_background the fit moves the photo onto other
  // colours with it.
  const ImageU8* matte = nullptr;
  // Where the capture measured the object's surface (a depth camera's
  // fused surface seen from this camera): per pixel the distance along its
  // ray to it, metres (1 channel, the photo's size; 0 where none). With
  // SplatFitOptions::depth_weight the fit keeps the facets' opacity on it.
  const ImageF* depth = nullptr;
};

// The image formation above, on the CPU: RGB floats in [0, 1], W x H x 3;
// `alpha_out` (optional) 1 - T_N per pixel.
ImageF render_splats(const std::vector<Splat>& splats, int coeffs, const Intrinsics& K,
                     const Eigen::Isometry3d& world_from_camera, const std::array<float, 3>& background,
                     ImageF* alpha_out = nullptr, int threads = 0, float pixel_filter_px2 = kSplatPixelFilterPx2);

struct SplatFitOptions {
  double seconds = 600;         // wall-clock budget of the whole fit
  int max_epochs = 0;           // > 0: also stop after this many passes over the photos
  int sh_degree = 1;            // 0..2
  int coarse_levels = 1;        // start this many halvings coarser than the facets given (their cells merged)
  bool refine = true;           // end one halving finer than the facets given
  double sigma_init = 0.6;      // footprint sigma / w at the start
  double opacity_init = 0.3;
  double lr_color = 0.01, lr_rest = 0.0005, lr_opacity = 0.05, lr_sigma = 0.01, lr_offset = 0.02;  // offset: per w
  double lr_final = 0.1;        // the rates fall exponentially to this fraction at each stage's end
  // The seconds budget's split over the stages: each stage gets this many
  // times the seconds of the one before. (max_epochs splits the passes over
  // the photos 1 : 1.5 : 2.25 ..., whatever this is.)
  double stage_time_growth = 1.5;
  double prune_opacity = 0.02;  // at refinement and at the end
  size_t max_facets = 600000;   // refinement splits facets up to this many (half that before the last stage)
  // Which facets refinement splits first. `usage`: the most pixel weight
  // over the stage's passes. `gradient`: the largest mean length of the
  // loss's gradient in the facet's image position over the steps that drew
  // it, as Kerbl et al. pick the Gaussians to densify ("3D Gaussian
  // Splatting for Real-Time Radiance Field Rendering", 2023): where the
  // photos pull a footprint hardest, one facet is too coarse.
  // Gradient is the default, chosen on lego's val split (33.24 dB against
  // 33.10 by usage, 1500-s fits); the rig bunny's held-out views are alike.
  enum class SplitBy { usage, gradient };
  SplitBy split_by = SplitBy::gradient;
  std::array<float, 3> background{0, 0, 0};
  // The image formation's pixel filter (pixels^2 at each pyramid level's own
  // pixels; see above): 0 draws every footprint at its own size.
  double pixel_filter_px2 = kSplatPixelFilterPx2;
  // Each step of a view with a matte (and no backdrop plate) moves its photo
  // onto a random colour under the matte, photo + (r - b)(1 - matte), and
  // composites the facets on the same r, as Mueller, Evans, Schied and
  // Keller train on RGBA data ("Instant Neural Graphics Primitives with a
  // Multiresolution Hash Encoding", 2022): opacity is then fitted to the
  // matte everywhere, not only where the object differs from b. The
  // training PSNR (and the divergence test's first figure) are measured on
  // such colours too.
  bool random_background = false;
  // The loss: (1 - w) x the mean colour term (`loss`) + w x (1 - SSIM), as
  // Kerbl et al. mix L1 and D-SSIM ("3D Gaussian Splatting for Real-Time
  // Radiance Field Rendering", 2023); 0: the colour term alone. The
  // training PSNR stays the squared error's.
  double ssim_weight = 0;
  // The colour term of that loss: the squared error, or the absolute error
  // as Kerbl et al. use it.
  enum class Loss { l2, l1 };
  Loss loss = Loss::l2;
  // Views with a depth: the loss adds depth_weight x the mean over their
  // depth pixels of (sum_i (|pc_i| - d) w_i / w)^2, w the facets' given
  // voxel: each pixel's compositing weights, spent off the measured surface
  // by |pc_i| - d, in voxels (see fit_detail::Behind). With few photos the
  // colour alone lets facets off the surface draw each photo, and a view
  // between them then shows them where they are (ghosts, blur); this keeps
  // them where the depth camera saw the surface, as depth-supervised
  // radiance fields do (Deng, Liu, Zhu and Ramanan, "Depth-supervised NeRF:
  // Fewer Views and Faster Training for Free", 2022).
  double depth_weight = 0;
  int threads = 0;
  std::vector<double> seconds_marks;  // snapshots of the facets at these seconds (error against run time)
  std::function<void(double fraction)> on_progress;

  Status validate() const;
};

struct SplatFitPoint {
  double seconds = 0;
  int epoch = 0;
  int scale = 1;           // the pyramid level's downscale factor
  double train_psnr_db = 0;  // the epoch's photos, at that level
  size_t splats = 0;
};

struct SplatFitSummary {
  std::vector<SplatFitPoint> curve;  // one point per epoch
  size_t initial = 0, refined_from = 0, split = 0, pruned = 0, final_count = 0;
  int epochs = 0;
  long steps = 0;
  double seconds = 0;
  // Where the seconds went: the error before the first step, projecting and
  // sorting, compositing forward and back, the optimiser's updates.
  double seconds_initial = 0, seconds_project = 0, seconds_raster = 0, seconds_update = 0;
  double initial_psnr_db = 0; // the photos at the first (coarsest) scale before any step
  double train_psnr_db = 0;   // the last full-resolution epoch (or the last epoch)
  // With depth_weight: the rms of sum_i (|pc_i| - d) w_i (metres) over the
  // pixels with a depth, at the start and in the last full-resolution epoch.
  double initial_depth_rms_m = 0, depth_rms_m = 0;
  std::vector<std::pair<double, std::vector<Splat>>> snapshots;  // at seconds_marks
};

// Halves the grid under `splats`: each becomes its eight children, one in
// each half-size sub-cell, placed and sized so that together they draw what
// the parent drew (see the definition for the rule).
std::vector<Splat> split_splats(const std::vector<Splat>& splats);

// Fits `splats` (anchors, voxel sizes and initial colours set by the caller;
// see init_splats) to `views`. On error (divergence, bad options) `splats` is
// left as it was.
Result<SplatFitSummary> fit_splats(std::vector<Splat>& splats, const std::vector<SplatView>& views,
                                   const SplatFitOptions& options);

// Facets at `anchors` (voxel w each), footprint and opacity from `options`,
// the colour's constant term the mean of the photos' pixels they project to.
std::vector<Splat> init_splats(const std::vector<Eigen::Vector3f>& anchors, float voxel,
                               const std::vector<SplatView>& views, const SplatFitOptions& options);

}  // namespace s2r
