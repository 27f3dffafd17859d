// The multi-scale environment map (Okumura, master's thesis, 2003;
// docs/references.md): a panorama
// prefiltered for every roughness at once, stored as one 3D texture. The
// direction from the volume's centre is the reflection vector r, the distance
// the smoothness lambda in [0, 1]: voxel t = r lambda holds the normalised
// Phong lobe of the panorama about r,
//
//   F(t) = sum_w P(w) (t^.w)^L dOmega / sum_w (t^.w)^L dOmega   over t^.w > 0,
//
// with the exponent tied to the radius so that the lobe stays resolvable by
// the voxels around it (I: intensity levels, s: voxels per side):
//
//   L = g(|t|) = -log(1/I) / -log cos(atan(2 / (|t| s))) = 2 log I / log1p((2 / (|t| s))^2).
//
// The right-hand form is exact and free of cancellation: g(0) = 0 (a uniform
// hemisphere), g grows as (|t| s)^2 log(I) / 2 and stays finite at |t| = 1.
//
// Building it (build_envmap) uses the structure of the problem instead of the
// thesis's brute force over every pixel for every voxel:
//  - a lobe of exponent L has angular scale 1/sqrt(L), so each voxel sums a
//    solid-angle-weighted pyramid level whose pixels are `samples_per_scale`
//    times finer than that scale (rough lobes read a coarse panorama, sharp
//    lobes the full one), and
//  - only over the cap where the weight is above `threshold` of its peak (the
//    thesis's weight threshold th), rows and columns of the cap found in closed
//    form on the equirectangular grid.
// Weights are exp(L log cos) with log cos = log1p(-chord^2 / 2), shifted by the
// largest in the cap: finite for any L. The result is compared, voxel by voxel,
// with the brute-force lobe (phong_lobe) by `s2r bench envmap`.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/report.h"
#include "core/result.h"
#include "trace/phong_reference.h"  // envmap_exponent, envmap_radius, roughness_to_exponent

namespace s2r {

struct EnvmapOptions {
  int size = 128;                  // s: voxels per side
  double intensity_levels = 256;   // I
  double threshold = 1e-3;         // th: weights below th x peak are left out
  double samples_per_scale = 2;    // pyramid pixels per lobe scale 1/sqrt(L)
  double max_scale_rad = 0.3;      // rough lobes: the hemisphere's edge still gets this resolution
  int threads = 0;                 // 0: every core
};

struct EnvmapStats {
  double seconds = 0;
  double pyramid_seconds = 0;
  size_t voxels = 0;            // computed (inside the unit ball plus a trilinear margin)
  size_t voxels_outside = 0;    // left out: no lookup ever reaches them
  double samples = 0;           // pixel weights evaluated
  std::vector<size_t> voxels_per_level;  // which pyramid level each voxel summed
  size_t memory_bytes = 0;      // the map as held (float RGB) ...
  size_t file_bytes = 0;        // ... and as written (half RGB, zip), 0 if not written
};

class EnvironmentMap {
 public:
  int size() const { return size_; }
  double intensity_levels() const { return levels_; }
  // Voxel (i, j, k) is t = ((i, j, k) + 0.5) 2 / s - 1; i runs along x.
  Eigen::Vector3d voxel_centre(int i, int j, int k) const;
  Eigen::Vector3f voxel(int i, int j, int k) const;
  // Trilinear lookup at t (|t| <= 1), as the GPU's 3D texture does it.
  Eigen::Vector3f lookup(const Eigen::Vector3d& t) const;
  // The glossy reflection of direction r at this exponent: lookup(r^ radius(L)).
  Eigen::Vector3f reflect(const Eigen::Vector3d& r, double exponent) const;
  // Raw float RGB, x fastest then y then z: what the renderer uploads.
  const std::vector<float>& data() const { return rgb_; }

  // OpenEXR, s wide and s*s tall (slice z at rows z*s ...), half RGB, with
  // attributes s2r:format "envmap", s2r:version, s2r:size, s2r:intensity_levels,
  // s2r:source. Written atomically; read validates every field and value.
  Status save(const std::filesystem::path& path, const std::string& source) const;
  static Result<EnvironmentMap> load(const std::filesystem::path& path);

 private:
  friend Result<EnvironmentMap> build_envmap(const Panorama&, const EnvmapOptions&, EnvmapStats*);
  int size_ = 0;
  double levels_ = 256;
  std::vector<float> rgb_;
};

Result<EnvironmentMap> build_envmap(const Panorama& panorama, const EnvmapOptions& options, EnvmapStats* stats = nullptr);

// Reads an equirectangular HDR (OpenImageIO). Non-finite or negative pixels
// are an error naming the first, or with `clamp` are replaced (NaN and
// negative by 0, +Inf by the largest finite value) and counted in a warning.
Result<Panorama> load_panorama(const std::filesystem::path& path, bool clamp, std::vector<std::string>* warnings);

}  // namespace s2r

namespace s2r {

// Error of a map against the brute-force lobe (phong_lobe), in `bands` equal
// bands of the radius lambda. At voxel centres (what was built) or, with
// `interpolated`, at random t read trilinearly (what a renderer sees: the
// reference then uses the exponent g(|t|) of the exact t).
struct EnvmapBandError {
  double lambda_lo = 0, lambda_hi = 0;
  size_t count = 0;
  double mean_display = 0, max_display = 0;  // |clamp(F,0,1) - clamp(ref,0,1)|, over channels: 8-bit view at exposure 1
  double mean_linear = 0, max_linear = 0;    // |F - ref| in the panorama's units
  double max_relative = 0;                   // |F - ref| / max(ref, 1/255)
};
struct EnvmapAccuracy {
  std::vector<EnvmapBandError> bands;
  EnvmapBandError all;
  double reference_seconds = 0;
};
Result<EnvmapAccuracy> envmap_accuracy(const EnvironmentMap& map, const Panorama& panorama, int samples, int bands,
                                       bool interpolated, unsigned seed, int threads = 0);

// The map's shells as panoramas (lambda = 1, 0.75, 0.5, 0.25, 0 top to bottom),
// each `width` x width/2, tone-mapped to 8-bit sRGB-ish gamma: a picture of
// what each roughness reflects.
ImageU8 envmap_preview(const EnvironmentMap& map, int width);

// `s2r envmap PANORAMA --out ENVMAP`: build, check against brute force on
// `check` voxels, write the map, a preview PNG beside it and a report.
struct EnvmapJob {
  std::filesystem::path panorama;
  std::filesystem::path out;  // the .exr
  EnvmapOptions options;
  bool clamp = false;
  int check = 300;  // voxels compared with brute force (0: none)
  unsigned seed = 1;
};
Result<Report> run_envmap_job(const EnvmapJob& job);

}  // namespace s2r
