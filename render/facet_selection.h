// Which facets a frame draws, and from which input cameras (microfacet
// billboarding with the octree LOD; docs/references.md). Runs on the CPU each frame, so what is left out is counted:
//
//   - frustum: the facet's bounding sphere lies outside the view's image or
//     in front of the near plane;
//   - back-facing: the facet has a measured normal pointing away from the eye
//     (fuzzy facets, normal 0, are never culled);
//   - no camera: no input camera sees the facet (models keep none, but a
//     hand-made or filtered one may).
//
// Camera choice: among the cameras that see the facet (its facet_cameras
// range), order by the angle at the facet centre between the direction to the
// eye and the direction to the camera, and blend the best k with the
// unstructured-lumigraph weights
//
//   w_i = (1 - theta_i / theta_k+1) / theta_i,   normalised,
//
// theta_k+1 being the angle of the first camera not used. A camera's weight
// falls to 0 just as it leaves the best k, so the image does not pop when the
// ranking changes. A camera at theta = 0 is exact: it alone is used (blending
// skipped).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "reconstruct/model.h"

namespace s2r {

inline constexpr int kMaxBlendCameras = 4;

// A view to draw: pinhole + lens model, pose. Image size = intrinsics size.
struct ViewCamera {
  Intrinsics K;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  Eigen::Vector3d eye() const { return world_from_camera.translation(); }
};

struct SelectionOptions {
  int cameras = 3;              // k, 1..kMaxBlendCameras
  bool frustum_cull = true;
  bool backface_cull = true;
  double backface_cos = -0.25;  // cull when normal . to_eye < this
  double near_m = 0.01;
  bool front_to_back = true;    // sort by distance: occluded fragments fail the depth test before shading
  // Cameras whose share of the blend is below this are left out and the rest
  // renormalised (each costs a full texel lookup per fragment); the colour
  // can then change by at most this share of the cameras' disagreement when
  // one crosses it. 0: keep every camera of the best k. At 0.1, s2r bench
  // render measured 3-20 % less frame time and +0.07..+0.19 dB held-out
  // PSNR on the rig (far cameras with small weights mostly add blur).
  double min_weight = 0.1;
  int threads = 0;
};

// One drawn facet: the per-instance data of the billboard pass (36 bytes).
struct FacetInstance {
  uint32_t facet;
  int32_t camera[kMaxBlendCameras];  // model camera index, -1 unused
  float weight[kMaxBlendCameras];    // sum to 1 over the used ones
};
static_assert(sizeof(FacetInstance) == 36, "FacetInstance is a vertex layout");

struct SelectionStats {
  size_t facets = 0;            // in the model
  size_t drawn = 0;
  size_t outside_frustum = 0;
  size_t back_facing = 0;
  size_t no_camera = 0;
  size_t exact_camera = 0;      // drawn from one camera at theta = 0: blending skipped
  size_t single_camera = 0;     // only one camera sees it
  size_t cameras_pruned = 0;    // blend entries below min_weight left out
  double seconds = 0;
};

// Blend weights for angles sorted ascending (radians); fills up to k entries
// of `weights`, returns how many are used.
int blend_weights(const double* sorted_angles, int count, int k, float* weights);
// Leaves out weights below `min_weight` (never the first, the largest) and
// renormalises; returns how many remain.
int prune_weights(float* weights, int used, double min_weight);

// Whether a sphere lies wholly outside a view (behind the near plane or off
// the image, with the lens' margin): the frustum test of facets and nodes.
bool sphere_outside_view(const Eigen::Isometry3d& camera_from_world, const Intrinsics& K, const Eigen::Vector3d& centre,
                         double radius, double near_m);

// Facets to choose from: a model's, or a level-of-detail hierarchy's
// (render/facet_lod.h), optionally only the listed ones.
struct FacetSet {
  const std::vector<FacetRecord>& facets;
  const std::vector<uint32_t>& facet_cameras;
  const std::vector<uint32_t>* candidates = nullptr;  // null: every facet
};

SelectionStats select_facets(const FacetSet& set, const std::vector<ModelCamera>& cameras, const ViewCamera& view,
                             const SelectionOptions& options, std::vector<FacetInstance>& out);
inline SelectionStats select_facets(const Model& model, const ViewCamera& view, const SelectionOptions& options,
                                    std::vector<FacetInstance>& out) {
  return select_facets(FacetSet{model.facets, model.facet_cameras}, model.cameras, view, options, out);
}

}  // namespace s2r
