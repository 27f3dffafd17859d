// Microfacets (Yamazaki, Sagawa, Kawasaki, Ikeuchi and Sakauchi, "Microfacet
// billboarding", 2002): one facet per voxel with evidence, its
// size chosen per region from the reliability of the geometry, the cameras
// that see it, and the error bound that ties facet size to camera spacing.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "reconstruct/fusion.h"
#include "reconstruct/model.h"

namespace s2r {

// --- The error bound -------------------------------------------------------
// A texel seen by camera c at the true surface point P is drawn on the facet
// billboard through the facet centre C, facing the view direction v. Along
// the camera ray P + t c the billboard is met at t = ((C - P).v) / (c.v); the
// texel moves on screen by |t| sin(alpha), alpha the angle between camera and
// view directions. Depth clipping draws it only where |t| = |d - D| < w/2, so
//     e <= (w/2) sin(alpha),  alpha <= delta = half the angular gap between
// neighbouring cameras (the nearest camera is chosen). The paper's example (30
// degree spacing, e < 0.13 w) is (w/2) sin 15 deg = 0.129 w. In pixels at
// viewing distance z with focal length f: e_px = f e / z.
double texel_error_bound(double w, double delta_rad);
// Largest w whose bound stays under `target_px` on screen.
double voxel_for_error(double target_px, double focal_px, double distance_m, double delta_rad);

// The facet size of a reconstruction: given, or the largest the error bound
// allows at the cameras' spacing and distance (`--voxel auto`), within
// limits of the photos' resolution and the object's size.
struct VoxelRequest {
  std::optional<double> given_m;  // nullopt: from the bound
  double target_error_px = 0.5;
  bool per_region = true;         // the base size is half the bound: unreliable regions get 2x
  double focal_px = 0;            // the input cameras' focal length
  double near_distance_m = 0;     // cameras to the object's near side
  double delta_rad = 0;           // the texel angle (half the widest camera gap, seen at the near side)
  double pixel_m = 0;             // an input pixel at the viewing distance
  double extent_m = 0;            // the object box's largest side
};
struct VoxelChoice {
  double base_m = 0;     // w: the finest facets
  double coarse_m = 0;   // the largest facets (2 w with per-region sizes)
  bool automatic = false;
  double bound_m = 0;    // automatic: the bound's w before the limits
  bool limited_by_pixels = false;  // automatic: held at 8 input pixels, not the bound
  std::vector<std::string> warnings;
};
VoxelChoice choose_voxel(const VoxelRequest& r);

struct CameraSpacing {
  double max_gap_rad = 0;       // the widest angle from a camera to its nearest neighbour, seen from `centre`
  double median_gap_rad = 0;
  double median_distance_m = 0;  // camera to centre
};
CameraSpacing camera_spacing(const std::vector<Eigen::Isometry3d>& world_from_camera, const Eigen::Vector3d& centre);

// The point closest (least squares) to all cameras' optical axes: the object
// on a turntable. Falls back to the cameras' centroid shifted along their mean
// axis when the axes are (nearly) parallel.
Eigen::Vector3d optical_axes_centre(const std::vector<Eigen::Isometry3d>& world_from_camera);

// --- Facets ----------------------------------------------------------------
// The visibility test reads a camera's depth on a grid of every `stride`-th
// pixel each way, from pixel (stride - 1) / 2: the pixels of a camera with
// focal lengths and image divided by `stride` (its rays are the same rays).
// A facet's test reads the grid point nearest its centre's projection.
Intrinsics visibility_grid(const Intrinsics& K, int stride);
// The widest stride whose grid spacing, at `far_m` from the camera, stays
// within w/3; at least 1. Against links from the rig bunny's true mesh
// (24 views), the fused surface's links disagree on 8.6 % at w = 6 mm with
// every pixel read and on 9.0 % with stride 2; at w = 3 mm a stride of 2
// (spacing w/2) took 5.2 % to 8.6 %, which w/3 rules out.
int visibility_stride(double w, double far_m, const Intrinsics& K);

struct FacetCamera {
  Intrinsics intrinsics;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  // Per-camera depth: distance along the ray, 0 = miss. Either the whole
  // image or the visibility grid's (visibility_grid(intrinsics, stride)).
  const ImageF* distance = nullptr;
  // Without `distance`: makes the camera's depth when build_facets comes to
  // this camera, which drops it once the facets are tested (a model without
  // textures never holds every camera's depth at once).
  std::function<ImageF()> distance_at;
  int stride = 1;  // the visibility grid's (see visibility_grid)
};

struct FacetOptions {
  double voxel_m = 0;            // finest facet size w0 (the fusion voxel)
  bool per_region = true;        // unreliable / fuzzy regions merge to 2 w0
  double reliable = 0.5;         // reliability at or above which a voxel keeps w0
  bool keep_unseen = false;      // keep facets no camera sees (nothing can texture them)
  int threads = 0;
};

struct FacetStats {
  size_t evidence = 0;           // voxels with evidence
  size_t facets = 0;
  size_t fine = 0, coarse = 0;   // facets of w0 and of 2 w0
  size_t fuzzy = 0;              // facets from silhouette evidence
  size_t unseen = 0;             // no camera sees the facet: left out unless keep_unseen
  size_t camera_links = 0;
  size_t occluded = 0;           // (facet, camera) pairs inside the image but hidden
  size_t outside_image = 0;      // (facet, camera) pairs out of the image
};

// Facet records and their camera lists. A camera sees a facet when its
// centre projects into the image and lies no further than the camera's depth
// there plus half the facet's diagonal (sqrt(3)/2 w).
FacetStats build_facets(const std::vector<EvidenceVoxel>& evidence, const std::vector<FacetCamera>& cameras,
                        const FacetOptions& options, std::vector<FacetRecord>& facets,
                        std::vector<uint32_t>& facet_cameras);

}  // namespace s2r
