// From a calibrated camera to OpenGL matrices.
//
// gl_projection() works directly on camera-frame points in the OpenCV
// convention (x right, y down, z forward), maps pixel centres (integer
// coordinates) to fragment centres, and puts image row 0 at the top of
// Framebuffer::read_rgb(). Lens distortion is not applied (pinhole part only).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/camera_model.h"

namespace s2r {

Eigen::Matrix4f gl_projection(const Intrinsics& K, float near_m, float far_m);

// clip = gl_projection(K) * camera_from_world * world point.
inline Eigen::Matrix4f gl_view_projection(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera,
                                          float near_m, float far_m) {
  return gl_projection(K, near_m, far_m) * world_from_camera.inverse().matrix().cast<float>();
}

}  // namespace s2r
