#include "render/point_renderer.h"

#include <epoxy/gl.h>

#include <utility>

namespace s2r {

namespace {
const char* kPointVertex = R"(#version 330 core
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 color;
uniform mat4 clip_from_world;
uniform float size_px;
out vec3 v_color;
void main() {
  gl_Position = clip_from_world * vec4(position, 1.0);
  gl_PointSize = size_px;
  v_color = color;
}
)";
const char* kPointFragment = R"(#version 330 core
in vec3 v_color;
out vec4 frag;
void main() { frag = vec4(v_color, 1.0); }
)";
}  // namespace

Result<PointRenderer> PointRenderer::create() {
  auto prog = GlProgram::build(kPointVertex, kPointFragment);
  if (!prog) return std::unexpected(prog.error());
  PointRenderer r(std::move(*prog));
  glGenVertexArrays(1, &r.vao_);
  glGenBuffers(1, &r.vbo_pos_);
  glGenBuffers(1, &r.vbo_col_);
  return r;
}

PointRenderer::PointRenderer(PointRenderer&& o) noexcept : program_(std::move(o.program_)) {
  std::swap(vao_, o.vao_);
  std::swap(vbo_pos_, o.vbo_pos_);
  std::swap(vbo_col_, o.vbo_col_);
  std::swap(count_, o.count_);
}
PointRenderer& PointRenderer::operator=(PointRenderer&& o) noexcept {
  program_ = std::move(o.program_);
  std::swap(vao_, o.vao_);
  std::swap(vbo_pos_, o.vbo_pos_);
  std::swap(vbo_col_, o.vbo_col_);
  std::swap(count_, o.count_);
  return *this;
}
PointRenderer::~PointRenderer() {
  if (vbo_pos_) glDeleteBuffers(1, &vbo_pos_);
  if (vbo_col_) glDeleteBuffers(1, &vbo_col_);
  if (vao_) glDeleteVertexArrays(1, &vao_);
}

void PointRenderer::upload(const std::vector<Eigen::Vector3f>& points,
                           const std::vector<std::array<uint8_t, 3>>& colors) {
  count_ = std::min(points.size(), colors.size());
  glBindVertexArray(vao_);
  glBindBuffer(GL_ARRAY_BUFFER, vbo_pos_);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(count_ * sizeof(Eigen::Vector3f)), points.data(),
               GL_STATIC_DRAW);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(Eigen::Vector3f), nullptr);
  glEnableVertexAttribArray(0);
  glBindBuffer(GL_ARRAY_BUFFER, vbo_col_);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(count_ * 3), colors.data(), GL_STATIC_DRAW);
  glVertexAttribPointer(1, 3, GL_UNSIGNED_BYTE, GL_TRUE, 3, nullptr);
  glEnableVertexAttribArray(1);
  glBindVertexArray(0);
}

void PointRenderer::draw(const Eigen::Matrix4f& clip_from_world, float size_px) const {
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glEnable(GL_PROGRAM_POINT_SIZE);
  glUseProgram(program_.id());
  glUniformMatrix4fv(program_.uniform("clip_from_world"), 1, GL_FALSE, clip_from_world.data());
  glUniform1f(program_.uniform("size_px"), size_px);
  glBindVertexArray(vao_);
  glDrawArrays(GL_POINTS, 0, static_cast<GLsizei>(count_));
  glBindVertexArray(0);
  glUseProgram(0);
}

}  // namespace s2r
