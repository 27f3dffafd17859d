// Fusion of registered views into a sparse volume (Curless and Levoy, "A volumetric method for
// building complex models from range images", 1996).
// OpenVDB is confined to fusion.cpp.
//
// Depth: a truncated signed distance per voxel (projective, z along the
// depth camera's axis, truncated at +tau and, behind the measured surface,
// clamped at -1.5 voxels so thin parts survive views from the other side),
// updated in every leaf node (8^3 voxels) within tau of a measured point, with
// the number of views that observed it and the spread of their signed
// distances (Welford), from which the voxel's reliability follows (agreement
// between views).
//
// Silhouettes: a visual hull carved coarse to fine from foreground masks (each
// cell's projected footprint must touch the foreground in every view that sees
// it whole). With depth as well, hull voxels that depth proves empty (in front
// of a measurement by more than tau over the whole footprint) or solid (behind
// one) are removed; what is left where depth has no sample is "fuzzy" evidence:
// thin strands and hair that the depth camera loses.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/mesh.h"
#include "reconstruct/octree.h"

namespace s2r {

struct DepthObservation {
  const ImageU16* depth = nullptr;  // 0 = no measurement
  double unit_m = 0.001;
  Intrinsics intrinsics;           // depth camera
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();  // depth camera
};

struct SilhouetteObservation {
  const ImageU8* mask = nullptr;  // 1 channel, non-zero = foreground
  Intrinsics intrinsics;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
};

// What a voxel with evidence holds once fusion is done.
struct EvidenceVoxel {
  Eigen::Vector3i ijk;         // centre = ijk * voxel
  Eigen::Vector3f centre;      // world, metres
  Eigen::Vector3f normal = Eigen::Vector3f::Zero();  // outward unit, or 0 when unknown
  float sdf_m = 0;             // fused signed distance (0 for hull evidence)
  float spread_m = 0;          // standard deviation of the views' signed distances
  int views = 0;               // views whose depth observed it
  bool fuzzy = false;          // silhouette evidence without a depth surface
  float reliability = 0;       // 0..1
};

struct FusionStats {
  size_t depth_samples = 0;     // depth pixels used
  size_t voxel_updates = 0;     // projective updates
  size_t views = 0;
  size_t views_without_depth = 0;
  size_t samples_outside_crop = 0;
};

struct HullStats {
  size_t cells_tested = 0;      // all levels
  size_t cells_interior = 0;    // kept untested: their parent lay wholly inside every silhouette
  size_t hull_voxels = 0;       // finest level, inside every silhouette
  size_t carved_by_depth = 0;   // free space in front of depth
  size_t solid_by_depth = 0;    // behind depth in every view that sees it
  size_t fuzzy_voxels = 0;
  int levels = 0;
};

class SparseVolume {
 public:
  // truncation_m: tau (>= voxel). crop: voxels outside are never created.
  SparseVolume(double voxel_m, double truncation_m, std::optional<Eigen::AlignedBox3d> crop = std::nullopt);
  ~SparseVolume();
  SparseVolume(const SparseVolume&) = delete;
  SparseVolume& operator=(const SparseVolume&) = delete;

  double voxel() const;
  double truncation() const;

  // Projective TSDF update from one depth image (parallel over leaf nodes).
  void integrate(const DepthObservation& view, int threads = 0);
  // The same as integrating the views one after the other (the same numbers),
  // in one pass: each leaf node is updated by every view that reaches it while
  // it is in cache. `on_view` is called once per view (progress).
  void integrate(const std::vector<DepthObservation>& views, int threads = 0,
                 const std::function<void()>& on_view = {});
  const FusionStats& fusion_stats() const;

  // Visual hull inside `box`, refined to the voxel size; with `depth` views the
  // hull is intersected with what depth leaves possible (see above). Replaces
  // any hull carved before.
  HullStats carve_hull(const std::vector<SilhouetteObservation>& views,
                       const std::vector<DepthObservation>& depth, const Eigen::AlignedBox3d& box,
                       int threads = 0);

  // Removes the hull voxels that at least `min_views` depth views show empty
  // (in front of every sample of their footprint by `margin_m`, at least the
  // voxel's half-diagonal; carve_hull's depth test uses the truncation
  // distance) and, without depth fused, takes the boundary
  // of what is left as the evidence again. Returns the voxels removed. For
  // depth that comes after the hull: per-camera depth refined by photo-
  // consistency (reconstruct/photo_depth.h).
  size_t carve_free(const std::vector<DepthObservation>& depth, int min_views, double margin_m, int threads = 0);

  // Depth surface voxels (a sign change to a 6-neighbour observed on both sides,
  // the smaller |sdf| of the two), then fuzzy hull voxels (or, with no depth at
  // all, the hull's boundary voxels). `reliability_sigma_m`: the spread at which
  // agreement counts as weak (reliability exp(-1/2) per view count factor).
  std::vector<EvidenceVoxel> evidence(double reliability_sigma_m) const;

  // Every observed voxel's fused signed distance (the octree's samples); with
  // silhouettes only, the distance to the hull's boundary.
  std::vector<std::pair<Eigen::Vector3i, float>> samples() const;
  // find_crossings(samples(), voxel, max_jump_voxels), the same crossings in
  // the same order, found leaf by leaf in parallel in the volume itself.
  std::vector<SurfaceCrossing> crossings(double max_jump_voxels) const;

  // The fused surface as triangles (OpenVDB volume-to-mesh at sdf = 0, limited
  // to observed surface voxels) plus the fuzzy/hull voxels' closed hull.
  // `evidence`: what evidence() returned (its depth voxels bound the mesher).
  // `depth_faces`: the count of the leading faces that are the depth surface.
  Mesh surface_mesh(const std::vector<EvidenceVoxel>& evidence, size_t* depth_faces = nullptr) const;

  // Where fitted facets may start (reconstruct/splat_fit.h): every voxel of
  // the visual hull, and depth-observed voxels within `band_m` of the fused
  // surface; voxel centres, world metres.
  std::vector<Eigen::Vector3f> fit_candidates(double band_m) const;

  size_t active_voxels() const;   // all grids
  size_t memory_bytes() const;    // all grids

  struct Impl;  // the grids (fusion.cpp's own; named here for its step functions)

 private:
  std::unique_ptr<Impl> impl_;
};

// Reliability of a depth voxel from its agreement between views: 0 with fewer
// than two views, growing to 1 with four or more, times exp(-spread^2 / (2 sigma^2)).
float depth_reliability(int views, float spread_m, double sigma_m);

// Foreground masks for object-centre sessions: the background colour is the
// median of the image border; a pixel is foreground when a channel differs
// from it by more than `threshold` levels (0 = from the border's spread).
// Returns nothing when the border is not uniform enough to be a backdrop.
struct Backdrop {
  std::vector<int> color;  // per channel: the border's median
  double spread = 0;       // the border's robust spread (1.4826 MAD), levels
};
Backdrop border_backdrop(const ImageU8& color);
std::optional<ImageU8> backdrop_mask(const ImageU8& color, double threshold = 0, double* border_spread = nullptr);

}  // namespace s2r
