// The peer `s2r bench register` measures against: PCL's pairwise
// point-to-plane ICP (IterativeClosestPointWithNormals), chained view to view
// as a pairwise tool is used: view k is aligned to view k-1, and the poses
// compose along the chain (its errors accumulate; nothing closes the loop).
#pragma once

#include <vector>

#include <Eigen/Geometry>

#include "reconstruct/registration.h"

namespace s2r {

struct IcpPeerOptions {
  int max_iterations = 30;       // per pair
  double max_correspondence_m = 0.01;
  double voxel_m = 0.001;        // both clouds down-sampled to this
};

// Poses (world_from_sensor) of `views` in order; views[0] keeps its initial pose.
std::vector<Eigen::Isometry3d> chain_icp(const std::vector<RegistrationView>& views, const IcpPeerOptions& options);

}  // namespace s2r
