// Coloured point splats: the session preview's drawing code, shared by the
// headless renderer and the window.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/result.h"
#include "render/gl_program.h"

namespace s2r {

class PointRenderer {
 public:
  static Result<PointRenderer> create();  // needs a current context
  PointRenderer(PointRenderer&&) noexcept;
  PointRenderer& operator=(PointRenderer&&) noexcept;
  PointRenderer(const PointRenderer&) = delete;
  ~PointRenderer();

  void upload(const std::vector<Eigen::Vector3f>& points, const std::vector<std::array<uint8_t, 3>>& colors);
  // Square splats of `size_px` pixels, depth-tested, into the bound framebuffer.
  void draw(const Eigen::Matrix4f& clip_from_world, float size_px) const;
  size_t count() const { return count_; }

 private:
  explicit PointRenderer(GlProgram p) : program_(std::move(p)) {}
  GlProgram program_;
  unsigned vao_ = 0, vbo_pos_ = 0, vbo_col_ = 0;
  size_t count_ = 0;
};

}  // namespace s2r
