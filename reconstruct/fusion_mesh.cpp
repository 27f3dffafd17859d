// OpenVDB's meshing and level-set tools for SparseVolume (fusion_grids.h).
#include "reconstruct/fusion.h"
#include "reconstruct/fusion_grids.h"

#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/TopologyToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <openvdb/tree/LeafManager.h>

namespace s2r {

using openvdb::Coord;

std::vector<std::pair<Eigen::Vector3i, float>> SparseVolume::samples() const {
  std::vector<std::pair<Eigen::Vector3i, float>> out;
  for (auto it = impl_->tsdf->cbeginValueOn(); it; ++it)
    if ((*it)[1] > 0 && it.isVoxelValue())
      out.push_back({Eigen::Vector3i(it.getCoord().x(), it.getCoord().y(), it.getCoord().z()), (*it)[0]});
  if (out.empty() && impl_->hull_only && impl_->hull && impl_->hull->activeVoxelCount() > 0) {
    // Silhouettes only: the signed distance to the hull's boundary.
    auto ls = openvdb::tools::topologyToLevelSet(*impl_->hull, 3, 0, 0, 0);
    for (auto it = ls->cbeginValueOn(); it; ++it)
      if (it.isVoxelValue())
        out.push_back({Eigen::Vector3i(it.getCoord().x(), it.getCoord().y(), it.getCoord().z()), *it});
  }
  return out;
}

Mesh SparseVolume::surface_mesh(const std::vector<EvidenceVoxel>& evidence, size_t* depth_faces) const {
  const Impl& m = *impl_;
  Mesh mesh;
  auto append = [&](const openvdb::tools::VolumeToMesh& mesher) {
    const int base = int(mesh.vertices.size());
    for (size_t i = 0; i < mesher.pointListSize(); ++i) {
      const auto& p = mesher.pointList()[i];
      mesh.vertices.emplace_back(p.x(), p.y(), p.z());
    }
    for (size_t n = 0; n < mesher.polygonPoolListSize(); ++n) {
      const auto& pool = mesher.polygonPoolList()[n];
      for (size_t i = 0; i < pool.numQuads(); ++i) {
        const auto& q = pool.quad(i);
        mesh.faces.emplace_back(base + int(q[0]), base + int(q[1]), base + int(q[2]));
        mesh.faces.emplace_back(base + int(q[0]), base + int(q[2]), base + int(q[3]));
      }
      for (size_t i = 0; i < pool.numTriangles(); ++i) {
        const auto& t = pool.triangle(i);
        mesh.faces.emplace_back(base + int(t[0]), base + int(t[1]), base + int(t[2]));
      }
    }
  };
  // Depth surface: the fused distances where observed, meshed only around
  // surface voxels (the band's far side borders unobserved space and must not
  // become a wall).
  // The distances: a float tree of the volume's topology, filled leaf by leaf
  // (a voxel never observed is left inactive at the background).
  const float background = float(m.tau);
  auto sdf = openvdb::FloatGrid::create(openvdb::FloatTree::Ptr(
      new openvdb::FloatTree(m.tsdf->tree(), background, openvdb::TopologyCopy())));
  sdf->setTransform(m.tsdf->transform().copy());
  sdf->setGridClass(openvdb::GRID_LEVEL_SET);
  {
    openvdb::tree::LeafManager<openvdb::FloatTree> lm(sdf->tree());
    lm.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, size_t) {
      const auto* src = m.tsdf->tree().probeConstLeaf(leaf.origin());
      for (openvdb::Index i = 0; i < openvdb::FloatTree::LeafNodeType::SIZE; ++i) {
        const bool observed = src && src->isValueOn(i) && src->getValue(i)[1] > 0;
        if (observed) leaf.setValueOn(i, src->getValue(i)[0]);
        else leaf.setValueOff(i, background);
      }
    });
  }
  auto mask = openvdb::BoolGrid::create(false);
  mask->setTransform(m.tsdf->transform().copy());
  {
    auto macc = mask->getAccessor();
    for (const auto& e : evidence)
      if (!e.fuzzy) macc.setValueOn(Coord(e.ijk.x(), e.ijk.y(), e.ijk.z()), true);
  }
  if (mask->activeVoxelCount() > 0) {
    openvdb::tools::dilateActiveValues(mask->tree(), 1, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::IGNORE_TILES);
    openvdb::tools::VolumeToMesh mesher(0.0, 0.0);
    mesher.setSurfaceMask(mask);
    mesher(*sdf);
    append(mesher);
  }
  if (depth_faces) *depth_faces = mesh.faces.size();
  // Fuzzy / hull voxels: the closed surface around them.
  if (m.fuzzy && m.fuzzy->activeVoxelCount() > 0) {
    const auto& source = m.hull_only ? m.hull : m.fuzzy;
    auto ls = openvdb::tools::topologyToLevelSet(*source, 2, 0, 0, 0);
    openvdb::tools::VolumeToMesh mesher(0.0, 0.0);
    mesher(*ls);
    append(mesher);
  }
  return mesh;
}

}  // namespace s2r
