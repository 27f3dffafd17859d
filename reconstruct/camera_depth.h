// Per-camera depth (DESIGN.md section 6.2): the fused geometry seen from every
// input camera, so each texel has its colour and the distance d to the object
// along its ray. Ray casting on Embree (only camera_depth.cpp includes it).
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
  // 0 where the ray misses. Pixels are sampled at their centres. With
  // `reach` (an image of K's size), a pixel's ray is cast only when its reach
  // is > 0, and only that far: a hit beyond it reads as a miss.
  ImageF distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, int threads = 0,
                        const ImageF* reach = nullptr) const;
  // Computes and keeps the pixel rays of `K` (distance_image does on first
  // use): callers that cast from several threads prepare them once, in parallel.
  void prepare_rays(const Intrinsics& K, int threads = 0) const;
  // Distance from `origin` along unit `dir` to the first hit, or 0.
  float distance(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir) const;
  size_t triangles() const;

 private:
  struct Impl;
  explicit MeshRaycaster(std::unique_ptr<Impl> impl);
  std::shared_ptr<const std::vector<Eigen::Vector3f>> rays_of(const Intrinsics& K, int threads) const;
  std::unique_ptr<Impl> impl_;
};

}  // namespace s2r
