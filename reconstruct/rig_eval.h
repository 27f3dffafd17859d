// Errors of a model against the synthetic rig's ground truth (tests and
// `s2r bench reconstruct`): facet centres against the true surface, per-camera
// depth against exact depth, and how much of the true strands the facets cover.
#pragma once

#include <filesystem>
#include <memory>
#include <vector>

#include "core/mesh.h"
#include "core/result.h"
#include "reconstruct/model.h"

namespace s2r {

class NeighbourIndex;

struct SurfaceError {
  size_t facets = 0;
  double within_size = 0;      // fraction of facet centres within their own size w of the surface
  double median_m = 0, p99_m = 0, max_m = 0;
};
// Distances from facet centres to the true surface, through dense samples of
// its mesh (spacing `sample_m`) in a k-d tree built once.
class SurfaceDistance {
 public:
  SurfaceDistance(const Mesh& truth, double sample_m);
  ~SurfaceDistance();
  SurfaceError error(const std::vector<FacetRecord>& facets) const;

 private:
  std::unique_ptr<NeighbourIndex> index_;
};
SurfaceError facet_surface_error(const std::vector<FacetRecord>& facets, const Mesh& truth, double sample_m);

struct DepthError {
  size_t pixels = 0;        // compared: both hit
  double median_m = 0, p90_m = 0;
  double missing = 0;       // fraction of truly covered pixels where the model has no depth
};
// The model's camera textures' distances against ground_truth/depth_color (z in
// the colour camera), over pixels where the true surface is seen.
Result<DepthError> camera_depth_error(const Model& model, const std::filesystem::path& model_dir,
                                      const std::filesystem::path& session_dir);

struct StrandCoverage {
  size_t strand_pixels = 0;
  double covered = 0;  // fraction of true strand pixels under some projected facet
  double background = 0;  // fraction of covered pixels where the truth has nothing (overreach)
};
// Facets drawn as squares of side sqrt(3) w facing each depth camera, against
// ground_truth/labels (2 = strand).
Result<StrandCoverage> strand_coverage(const Model& model, const std::filesystem::path& session_dir);

struct TexelError {
  double angle_deg = 0;   // the view's turn from each camera about the ring axis (seen from the centre)
  size_t texels = 0;      // drawn texels measured
  double median_px = 0, p99_px = 0, max_px = 0;  // on-screen displacement
  double max_ratio = 0;   // largest e / ((f / z) (w/2) sin(alpha)), alpha the angle between the
                          // camera ray and the view ray at the texel: <= 1 when the bound holds
};
// The billboard geometry of microfacet billboarding measured on the rig: true
// surface points seen by each model camera (exact depth) are drawn on every
// facet whose billboard, facing a view turned by `angle_deg` about the
// cameras' ring axis, passes the depth clip |d - D| < w/2; the displacement
// from the true point is measured in pixels of that view (the camera's focal
// length).
Result<TexelError> measure_texel_error(const Model& model, const std::filesystem::path& session_dir, double angle_deg,
                                       int pixel_stride = 4);

}  // namespace s2r
