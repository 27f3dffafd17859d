// Meshes for the tracer: a mesh's level-of-detail chain and the icosphere
// that tests, props and the glossy comparison use.
#pragma once

#include <cstddef>

#include <Eigen/Core>

#include "core/mesh.h"
#include "core/result.h"
#include "trace/raytracer.h"

namespace s2r {

// A mesh with its level-of-detail chain: simplified to at most `n_max`
// triangles, then levels down to `n_min`. Vertex normals are computed.
Result<RtMesh> lod_mesh(const Mesh& mesh, size_t n_max, size_t n_min, int levels);
// A closed unit sphere (subdivided icosahedron), for tests and props.
Mesh icosphere(int subdivisions);
// An icosphere of this centre and radius as a one-level tracer mesh with normals.
RtMesh sphere_mesh(int subdivisions, const Eigen::Vector3d& centre = Eigen::Vector3d::Zero(), double radius = 1);

}  // namespace s2r
