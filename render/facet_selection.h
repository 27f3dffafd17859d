// Which facets a frame draws, and from which input cameras (DESIGN.md §6.3,
// §7, §13). Runs on the CPU each frame, so what is left out is counted:
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
  double seconds = 0;
};

// Blend weights for angles sorted ascending (radians); fills up to k entries
// of `weights`, returns how many are used.
int blend_weights(const double* sorted_angles, int count, int k, float* weights);

SelectionStats select_facets(const Model& model, const ViewCamera& view, const SelectionOptions& options,
                             std::vector<FacetInstance>& out);

}  // namespace s2r
