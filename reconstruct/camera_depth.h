// Per-camera depth for microfacet billboarding: the fused geometry seen from every
// input camera, so each texel has its colour and the distance d to the object
// along its ray. Two ways to the same image: a z-buffer rasterizer whose
// per-pixel test is the exact ray-triangle test (what reconstruct uses: its
// cost goes with the triangles, not the pixels), and ray casting on Embree
// (the reference; only camera_depth.cpp includes it).
#pragma once

#include <memory>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/mesh.h"
#include "core/result.h"

namespace s2r {

class MeshRaycaster {
 public:
  static Result<std::unique_ptr<MeshRaycaster>> create(const Mesh& mesh);
  ~MeshRaycaster();

  // Distance along each pixel's ray (through the lens model) to the first hit,
  // 0 where the ray misses. Pixels are sampled at their centres.
  ImageF distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, int threads = 0) const;
  // Distance from `origin` along unit `dir` to the first hit, or 0.
  float distance(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir) const;
  size_t triangles() const;

 private:
  struct Impl;
  explicit MeshRaycaster(std::unique_ptr<Impl> impl);
  std::shared_ptr<const std::vector<Eigen::Vector3f>> rays_of(const Intrinsics& K, int threads) const;
  std::unique_ptr<Impl> impl_;
};

// Rasterizes a mesh into cameras' distance images. Every pixel keeps the
// nearest triangle whose cone from the camera centre holds the pixel's ray (the
// lens model's, through the pixel centre) and the distance along that ray to
// the triangle's plane: the same test as a ray cast, so the image equals
// MeshRaycaster's up to float rounding. A triangle's pixels are found from its
// vertices' projections through the lens (a pixel of margin; triangles over 32
// pixels wide under distortion split for the bound only). Shared edges are
// tested with the same vector from both sides, so the surface has no cracks.
// Triangles outside the view are culled before any pixel is touched.
//
// Which faces can be seen: kBoth draws every face; kInwardWound is for a
// surface whose faces are wound with their normals (b - a) x (c - a) pointing
// into the object, as OpenVDB's volume-to-mesh winds the fused surface, and
// leaves out the faces whose outside looks away from the camera (on a closed
// surface always behind a front face; on the rig bunny at 1.5 mm about 20
// pixels a camera change, where a hole in the fused surface shows its inside).
class MeshRasterizer {
 public:
  enum class Faces { kBoth, kInwardWound };
  explicit MeshRasterizer(const Mesh& mesh, Faces faces = Faces::kBoth);
  ~MeshRasterizer();

  struct Stats {
    size_t triangles_drawn = 0;     // at least one pixel tested
    size_t triangles_culled = 0;    // behind the camera or outside the view
    size_t back_faces = 0;          // left out (Faces::kInwardWound)
    size_t back_faces_in_runs = 0;  // of which in runs of faces all turned away, not tested one by one
    size_t pixels_tested = 0;
  };
  // Distance along each pixel's ray to the nearest triangle, 0 where none.
  // Safe to call from several threads at once.
  ImageF distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, Stats* stats = nullptr) const;
  // Sets up the pixel rays of `K` (distance_image does on first use): the
  // image's window through the lens; each 16 x 16 tile's rays are then made
  // when a triangle first covers it, by whichever drawing thread comes first.
  void prepare(const Intrinsics& K, int threads = 0) const;
  size_t triangles() const;
  // Ray tiles made so far and in all, over every intrinsics prepared.
  struct RayTiles {
    size_t made = 0, total = 0;
  };
  RayTiles ray_tiles() const;

 private:
  struct Impl;
  std::shared_ptr<const void> rays_of(const Intrinsics& K, int threads) const;
  std::unique_ptr<Impl> impl_;
};

}  // namespace s2r
