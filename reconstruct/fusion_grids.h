#pragma once
// The sparse volume's grids, shared by the translation units that implement
// SparseVolume (fusion.cpp: integration, the hull, evidence, crossings;
// fusion_mesh.cpp: OpenVDB's meshing and level-set tools, whose templates are
// the slowest code of the project to compile and so build beside the rest).
// Only those two files include it: OpenVDB stays out of every other header.

#include "reconstruct/fusion.h"

#include <openvdb/openvdb.h>

namespace s2r {

// Per voxel: (mean signed distance in metres, number of views, Welford M2).
using TsdfGrid = openvdb::Vec3SGrid;
using TsdfTree = TsdfGrid::TreeType;

struct SparseVolume::Impl {
  double voxel, tau;
  // Behind a measured surface distances are clamped at a voxel and a half:
  // objects thinner than tau would otherwise be overwritten by the deep
  // negative band of the views from the other side.
  double behind;
  std::optional<Eigen::AlignedBox3d> crop;
  TsdfGrid::Ptr tsdf;
  openvdb::MaskGrid::Ptr hull;   // hull voxels (after depth tests)
  openvdb::MaskGrid::Ptr fuzzy;  // hull voxels without a depth surface
  bool hull_only = false;        // no depth views were given to the hull
  FusionStats stats;

  bool in_crop(const Eigen::Vector3d& p) const { return !crop || crop->contains(p); }
  Eigen::Vector3d centre(const openvdb::Coord& c) const { return Eigen::Vector3d(c.x(), c.y(), c.z()) * voxel; }
};

}  // namespace s2r
