#include "trace/meshes.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>
#include <vector>

namespace s2r {
using Eigen::Vector3i;

RtMesh sphere_mesh(int subdivisions, const Eigen::Vector3d& centre, double radius) {
  const Mesh m = icosphere(subdivisions);
  RtMesh out;
  for (const auto& v : m.vertices) out.vertices.push_back((centre + radius * v.cast<double>()).cast<float>());
  out.normals = m.normals;
  out.levels = {m.faces};
  return out;
}

Result<RtMesh> lod_mesh(const Mesh& mesh, size_t n_max, size_t n_min, int levels) {
  if (mesh.faces.empty()) return fail("mesh has no triangles");
  if (n_max < 1 || n_min < 1 || n_min > n_max) return fail("need 1 <= N_min <= N_max");
  std::vector<Vector3i> top = mesh.faces;
  if (top.size() > n_max) {
    auto c = build_lod_chain(mesh.vertices, mesh.faces, n_max, 2);
    if (!c) return std::unexpected(c.error());
    top = c->back();
  }
  // Keep only the vertices the finest level uses.
  std::vector<int> remap(mesh.vertices.size(), -1);
  RtMesh out;
  for (auto& f : top)
    for (int k = 0; k < 3; ++k) {
      int& r = remap[f[k]];
      if (r < 0) {
        r = static_cast<int>(out.vertices.size());
        out.vertices.push_back(mesh.vertices[f[k]]);
        if (!mesh.colors.empty()) out.colors.push_back(mesh.colors[f[k]]);
      }
      f[k] = r;
    }
  auto chain = build_lod_chain(out.vertices, top, n_min, levels);
  if (!chain) return std::unexpected(chain.error());
  out.levels = std::move(*chain);
  Mesh tmp;
  tmp.vertices = out.vertices;
  tmp.faces = out.levels[0];
  tmp.compute_vertex_normals();
  out.normals = std::move(tmp.normals);
  return out;
}

Mesh icosphere(int subdivisions) {
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  Mesh m;
  m.vertices = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  m.faces = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
             {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
             {3, 8, 9},  {4, 9, 5},  {2, 4, 11},  {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (auto& v : m.vertices) v.normalize();
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      m.vertices.push_back((m.vertices[a] + m.vertices[b]).normalized());
      const int id = static_cast<int>(m.vertices.size()) - 1;
      mid.emplace(key, id);
      return id;
    };
    std::vector<Vector3i> faces;
    for (const auto& f : m.faces) {
      const int a = midpoint(f[0], f[1]), b = midpoint(f[1], f[2]), c = midpoint(f[2], f[0]);
      faces.insert(faces.end(), {{f[0], a, c}, {f[1], b, a}, {f[2], c, b}, {a, b, c}});
    }
    m.faces = std::move(faces);
  }
  m.compute_vertex_normals();
  return m;
}

}  // namespace s2r
