// A model's surface as a binary glTF 2.0 file (.glb) with a texture atlas
// baked from the photos (docs/formats.md, "Exports"):
//
//  - the mesh: the octree's patch mesh (or the fused surface), in metres,
//    +Y up: the model's world z axis (the turntable's, the table frame's up)
//    becomes glTF's +Y, world (x, y, z) -> glTF (x, z, -y);
//  - the texture: one PNG atlas, each triangle in a square cell of its own
//    (every texel of the cell filled, so bilinear filtering never reads a
//    neighbour's), each texel the blend of up to three cameras that see its
//    point (the model's camera images, their distances as the visibility
//    test: the depth clipping of the billboards), weighted by how head-on
//    they see the triangle; KHR_materials_unlit (the light is in the photos);
//  - the capture's cameras as glTF perspective cameras (vertical field of view
//    and aspect ratio; glTF has no principal point or lens distortion).
#pragma once

#include <filesystem>
#include <string>

#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct GltfExportJob {
  std::filesystem::path model, out;
  std::string mesh = "patch";  // patch | surface
  int atlas_max = 4096;        // atlas side at most, texels
  int max_cell = 32;           // texels per triangle cell side at most
  int threads = 0;
};

Result<Report> export_gltf(const GltfExportJob& job);

}  // namespace s2r
