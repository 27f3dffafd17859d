// The whole job behind `s2r reconstruct`: a session and its poses in, a model
// out (docs/formats.md, "Model"): fusion, microfacets with per-region size,
// per-camera RGBA + depth textures, the fused surface mesh, and a report with
// the seconds of every step, counts, memory, voxel sizes and what was skipped.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Geometry>

#include "capture/session.h"
#include "core/report.h"
#include "core/result.h"
#include "reconstruct/microfacets.h"
#include "reconstruct/rig_eval.h"
#include "reconstruct/splat_fit.h"

namespace s2r {

// Where the geometry comes from: fused depth, the visual hull of the
// silhouettes, both, or `automatic` (depth, plus the hull against a uniform
// backdrop; the hull alone without depth).
enum class Geometry { automatic, depth, hull, both };
// "auto", "depth", "hull", "both" (inline: the command line's front names
// the default without linking the stage).
constexpr std::string_view geometry_name(Geometry g) {
  switch (g) {
    case Geometry::automatic: return "auto";
    case Geometry::depth: return "depth";
    case Geometry::hull: return "hull";
    case Geometry::both: return "both";
  }
  return "auto";
}
constexpr std::optional<Geometry> parse_geometry(std::string_view name) {  // the inverse
  for (Geometry g : {Geometry::automatic, Geometry::depth, Geometry::hull, Geometry::both})
    if (geometry_name(g) == name) return g;
  return std::nullopt;
}

struct ReconstructJob {
  std::filesystem::path session;
  std::filesystem::path out;          // the model folder
  std::filesystem::path poses;        // optional: registered poses (s2r register)
  std::filesystem::path calibration;  // optional: intrinsics, depth extrinsic, table axis
  std::optional<double> voxel_m;      // nullopt: from the error bound (--voxel auto)
  Geometry geometry = Geometry::automatic;
  std::vector<int> holdout;           // frames left out entirely
  double target_error_px = 0.5;       // on-screen texel error the auto voxel keeps under
  double truncation_voxels = 4;       // tau in voxels
  bool per_region = true;             // unreliable / fuzzy regions get 2x larger facets
  bool textures = true;               // write cameras/NNNN.exr
  // Captures without depth: each camera's depth searched behind the hull by
  // photo-consistency, carving what it shows empty (reconstruct/photo_depth.h).
  bool photo_depth = false;
  // > 0: fit billboards to the photos for this many seconds (splats.bin;
  // reconstruct/splat_fit.h), starting from the hull's voxels and the
  // fused surface's band; 0: no fit.
  double fit_seconds = 0;
  int fit_epochs = 0;                 // > 0: the fit also stops after this many passes over the photos
  int fit_sh_degree = 1;              // view-dependent colour: 0 (none) .. 2
  size_t fit_max_facets = SplatFitOptions{}.max_facets;  // refinement splits up to this many facets
  double fit_stage_growth = SplatFitOptions{}.stage_time_growth;  // each stage's seconds over the one before's
  bool fit_random_background = false;  // views with a matte: fit on random colours under it (SplatFitOptions)
  // The fit's loss: (1 - w) squared error + w (1 - SSIM) (SplatFitOptions).
  // 0.2, as 3D Gaussian Splatting mixes them: chosen on lego's val split
  // (all 100 views, 1500-s fit: 33.11 dB / SSIM 0.974 against 32.15 / 0.959
  // with the squared error alone; docs/cli.md).
  double fit_ssim_weight = 0.2;
  // The loss's colour term: l2 (squared error) | l1 (absolute error)
  // (SplatFitOptions::loss). l1, as 3D Gaussian Splatting fits: chosen on
  // lego's val split (all 100 views, 1500-s fit: 33.99 dB / SSIM 0.9764
  // against 33.64 / 0.9757 with l2; docs/cli.md).
  std::string fit_loss = "l1";
  // The fitted billboards' pixel filter, pixels^2 (splat_fit.h; 0: none).
  double fit_pixel_filter_px2 = kSplatPixelFilterPx2;
  std::string fit_split = "gradient";     // which facets refinement splits first: usage | gradient (SplatFitOptions::split_by)
  double fit_depth_weight = 0;         // the fit's depth term where the capture has depth (SplatFitOptions::depth_weight)
  std::vector<double> fit_snapshots;  // seconds: also write splats_<s>s.bin at these (error against run time)
  int threads = 0;

  // The options' own ranges, an error naming the field ("target_error_px:
  // must be > 0 pixels"); what depends on the session is checked by the job.
  Status validate() const;
};

// The model's error against the synthetic rig's ground truth.
struct ReconstructTruth {
  SurfaceError all, fine;                 // facet centres to the true surface (fine: facets of w)
  std::optional<DepthError> camera_depth;  // the cameras' textures' depth (with textures)
  std::optional<StrandCoverage> strands;   // scenes with strands
};

// What a reconstruction did, typed (as Ceres' Solver::Summary): what benches
// and tests read, and the whole report (seconds and CPU seconds per step,
// every count, what was skipped, warnings) for report.json.
struct ReconstructSummary {
  Geometry geometry = Geometry::automatic;  // what `automatic` resolved to
  VoxelChoice voxel;                        // the facet sizes and how they were chosen
  double view_distance_m = 0, near_distance_m = 0;
  size_t cameras = 0, held_out_views = 0, views_without_depth = 0;
  FacetStats facets;
  size_t camera_depth_triangles_drawn = 0;
  size_t camera_depth_pixels_outside_matte = 0;  // cameras' distances cut where their view's matte is 0
  double seconds = 0, seconds_fusion = 0;  // the build (the truth check not counted), fusion alone
  std::optional<ReconstructTruth> truth;   // sessions with ground truth only
  std::optional<SplatFitSummary> fit;      // with fit_seconds > 0 (snapshots not kept)
  Report report;

  const Report& to_report() const { return report; }
  std::string brief() const { return report.brief(); }
};

Result<ReconstructSummary> run_reconstruct_job(const ReconstructJob& job);

}  // namespace s2r
