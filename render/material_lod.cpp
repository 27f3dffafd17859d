#include "render/material_lod.h"

#include <epoxy/gl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

#include <spdlog/fmt/fmt.h>

#include "render/gl_program.h"
#include "render/gl_context.h"

namespace s2r {

double seed_material_threshold(double R, double D) {
  // Eq. 4.1 of Tsutsumi (2010): slope and intercept per relief row.
  static const double rows[][3] = {{0, 0.331, 59.5},   {200, 0.327, 64.7}, {400, 0.325, 68.8},
                                   {600, 0.324, 74.0}, {800, 0.327, 69.0}, {1000, 0.327, 69.0}};
  R = std::clamp(R, 0.0, 1000.0);
  D = std::clamp(D, 0.0, 1000.0);
  const int i = std::min(4, static_cast<int>(D / 200));
  const double f = (D - rows[i][0]) / 200;
  const double a = rows[i][1] * R + rows[i][2], b = rows[i + 1][1] * R + rows[i + 1][2];
  return a + f * (b - a);
}

double normalised_repeats(double repeats) { return std::clamp(1000 * (repeats - 2) / 8, 0.0, 1000.0); }
double normalised_depth(double depth) { return std::clamp(1000 * depth / 0.1, 0.0, 1000.0); }

ReliefMaterial brick_material(int size, double repeats, double depth) {
  ReliefMaterial m;
  m.repeats = repeats;
  m.depth = depth;
  m.albedo = ImageU8(size, size, 3);
  m.height = ImageF(size, size, 1);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> speck(-0.08f, 0.08f);
  const int rows = 4, cols = 2;  // bricks per tile
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const double v = (y + 0.5) / size * rows;
      const int row = static_cast<int>(v);
      const double u = (x + 0.5) / size * cols + (row % 2 ? 0.5 : 0.0);
      const double fu = u - std::floor(u), fv = v - row;
      // distance to the brick's edge in brick units, bevel 0.06, mortar 0.04
      const double edge = std::min({fu * 2, (1 - fu) * 2, fv, 1 - fv});
      const double h = std::clamp((edge - 0.04) / 0.06, 0.0, 1.0);
      m.height.at(x, y, 0) = static_cast<float>(h);
      const int brick = static_cast<int>(std::floor(u)) * 7 + row * 13;
      const float tint = 0.1f * static_cast<float>((brick * 37) % 5) / 4;
      const float s = speck(rng);
      const float r = h > 0 ? 0.62f + tint + s : 0.55f + s, g = h > 0 ? 0.28f + tint / 2 + s : 0.52f + s,
                  b = h > 0 ? 0.2f + s : 0.48f + s;
      m.albedo.at(x, y, 0) = static_cast<uint8_t>(std::clamp(r, 0.f, 1.f) * 255);
      m.albedo.at(x, y, 1) = static_cast<uint8_t>(std::clamp(g, 0.f, 1.f) * 255);
      m.albedo.at(x, y, 2) = static_cast<uint8_t>(std::clamp(b, 0.f, 1.f) * 255);
    }
  return m;
}

namespace {

const char* kMaterialLodVertex = R"(#version 430 core
layout(location = 0) in vec3 pos;
layout(location = 1) in vec3 nrm;
layout(location = 2) in vec3 tan;
layout(location = 3) in vec3 bit;
layout(location = 4) in vec2 tex;
uniform mat4 view_proj;
out vec3 wpos, wn, wt, wb;
out vec2 uv;
void main() {
  wpos = pos; wn = nrm; wt = tan; wb = bit; uv = tex;
  gl_Position = view_proj * vec4(pos, 1.0);
}
)";

const char* kMaterialLodFragment = R"(#version 430 core
in vec3 wpos, wn, wt, wb;
in vec2 uv;
out vec4 colour;
uniform sampler2D albedo, height;
uniform vec3 eye, light_dir;
uniform float repeats, depth, threshold, blend, vnear, vfar;
uniform int method, flat_material, min_layers, max_layers;

vec2 dx, dy;  // tile-uv derivatives, taken before any branch

vec3 normal_at(vec2 t) {
  vec2 e = 1.0 / vec2(textureSize(height, 0));
  float hu = textureGrad(height, t + vec2(e.x, 0), dx, dy).r - textureGrad(height, t - vec2(e.x, 0), dx, dy).r;
  float hv = textureGrad(height, t + vec2(0, e.y), dx, dy).r - textureGrad(height, t - vec2(0, e.y), dx, dy).r;
  return normalize(vec3(-depth * hu / (2.0 * e.x), -depth * hv / (2.0 * e.y), 1.0));
}

vec3 shade(vec2 t, vec3 n_tangent, mat3 tbn) {
  vec3 n = normalize(tbn * n_tangent);
  vec3 a = textureGrad(albedo, t, dx, dy).rgb;
  return a * (0.25 + 0.75 * max(dot(n, normalize(light_dir)), 0.0));
}

// Parallax occlusion mapping: march the height field along the view ray in
// tangent space (more layers at grazing angles), then one secant step.
vec2 parallax(vec2 t, vec3 v_tangent) {
  float n = mix(float(max_layers), float(min_layers), clamp(abs(v_tangent.z), 0.0, 1.0));
  float layer = 1.0 / n;
  vec2 shift = v_tangent.xy / max(v_tangent.z, 0.05) * depth / n;
  float cur = 1.0;
  vec2 c = t;
  float h = textureGrad(height, c, dx, dy).r;
  for (int i = 0; i < 256 && h < cur; ++i) {
    c -= shift;
    cur -= layer;
    h = textureGrad(height, c, dx, dy).r;
  }
  vec2 prev = c + shift;
  float after = h - cur;
  float before = textureGrad(height, prev, dx, dy).r - (cur + layer);
  float w = after / (after - before);
  return mix(c, prev, clamp(w, 0.0, 1.0));
}

void main() {
  vec2 t = uv * repeats;
  dx = dFdx(t);
  dy = dFdy(t);
  vec3 n = normalize(wn);
  vec3 tt = normalize(wt - n * dot(n, wt));
  vec3 bb = normalize(cross(n, tt)) * sign(dot(cross(n, tt), wb));
  mat3 tbn = mat3(tt, bb, n);
  vec3 to_eye = normalize(eye - wpos);
  vec3 v = vec3(dot(to_eye, tt), dot(to_eye, bb), dot(to_eye, n));
  // 0 texture, 1 bump, 2 parallax; LOD picks the pair and the mix.
  int detailed = method, simple = method;
  float mixw = 0.0;
  if (method == 4) {
    float V = clamp((length(wpos - eye) - vnear) / (vfar - vnear), 0.0, 1.0) * 255.0;
    colour = vec4(floor(V) / 255.0, fract(V), 0.0, 1.0);
    return;
  }
  if (method == 3) {
    detailed = flat_material != 0 ? 1 : 2;
    simple = flat_material != 0 ? 0 : 1;
    float d = length(wpos - eye);
    float V = 1000.0 * clamp((d - vnear) / (vfar - vnear), 0.0, 1.0);
    mixw = smoothstep(threshold - blend, threshold + blend, V);
  }
  vec3 c = vec3(0.0);
  if (mixw < 1.0) {
    vec3 a;
    if (detailed == 2) { vec2 p = parallax(t, v); a = shade(p, normal_at(p), tbn); }
    else if (detailed == 1) a = shade(t, normal_at(t), tbn);
    else a = shade(t, vec3(0, 0, 1), tbn);
    c += (1.0 - mixw) * a;
  }
  if (mixw > 0.0) {
    vec3 a;
    if (simple == 1) a = shade(t, normal_at(t), tbn);
    else a = shade(t, vec3(0, 0, 1), tbn);
    c += mixw * a;
  }
  colour = vec4(c, 1.0);
}
)";

}  // namespace

struct MaterialRenderer::Gpu {
  GlProgram program;
  GLuint vao = 0, vbo = 0, albedo = 0, height = 0;
  GLsizei vertices = 0;
  explicit Gpu(GlProgram p) : program(std::move(p)) {}
  ~Gpu() {
    glDeleteVertexArrays(1, &vao);
    glDeleteBuffers(1, &vbo);
    glDeleteTextures(1, &albedo);
    glDeleteTextures(1, &height);
  }
};

MaterialRenderer::~MaterialRenderer() = default;

Result<std::unique_ptr<MaterialRenderer>> MaterialRenderer::create(const RtMesh& mesh, const ReliefMaterial& m) {
  if (auto v = mesh.validate("relief mesh"); !v) return std::unexpected(v.error());
  if (mesh.uvs.empty() || mesh.normals.empty()) return fail("a relief mesh needs normals and uvs");
  if (m.albedo.empty() || m.albedo.channels < 3 || m.height.empty() || m.height.channels != 1)
    return fail("a relief material needs an RGB albedo and a 1-channel height map");
  if (!(m.repeats > 0) || !(m.depth >= 0) || !std::isfinite(m.repeats) || !std::isfinite(m.depth))
    return fail("relief material: repeats must be > 0 and depth >= 0");
  auto program = GlProgram::build(kMaterialLodVertex, kMaterialLodFragment);
  if (!program) return std::unexpected(program.error());
  std::unique_ptr<MaterialRenderer> r(new MaterialRenderer);
  r->gpu_ = std::make_unique<Gpu>(std::move(*program));
  r->threshold_ = seed_material_threshold(normalised_repeats(m.repeats), normalised_depth(m.depth));
  r->flat_ = normalised_depth(m.depth) == 0;
  r->repeats_ = static_cast<float>(m.repeats);
  r->depth_ = static_cast<float>(m.depth);
  Gpu& g = *r->gpu_;
  // Unshared vertices per triangle with the triangle's tangent frame from its uvs.
  std::vector<float> vb;
  for (const auto& f : mesh.levels.front()) {
    const Eigen::Vector3f e1 = mesh.vertices[f[1]] - mesh.vertices[f[0]], e2 = mesh.vertices[f[2]] - mesh.vertices[f[0]];
    const Eigen::Vector2f d1 = mesh.uvs[f[1]] - mesh.uvs[f[0]], d2 = mesh.uvs[f[2]] - mesh.uvs[f[0]];
    const float det = d1.x() * d2.y() - d2.x() * d1.y();
    Eigen::Vector3f t = Eigen::Vector3f::UnitX(), b = Eigen::Vector3f::UnitY();
    if (std::abs(det) > 1e-12f) {
      t = (e1 * d2.y() - e2 * d1.y()) / det;
      b = (e2 * d1.x() - e1 * d2.x()) / det;
    }
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3f& p = mesh.vertices[f[k]];
      const Eigen::Vector3f& n = mesh.normals[f[k]];
      const Eigen::Vector2f& uv = mesh.uvs[f[k]];
      vb.insert(vb.end(), {p.x(), p.y(), p.z(), n.x(), n.y(), n.z(), t.x(), t.y(), t.z(), b.x(), b.y(), b.z(), uv.x(), uv.y()});
    }
  }
  g.vertices = static_cast<GLsizei>(vb.size() / 14);
  glGenVertexArrays(1, &g.vao);
  glBindVertexArray(g.vao);
  glGenBuffers(1, &g.vbo);
  glBindBuffer(GL_ARRAY_BUFFER, g.vbo);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(vb.size() * sizeof(float)), vb.data(), GL_STATIC_DRAW);
  const int sizes[] = {3, 3, 3, 3, 2};
  size_t offset = 0;
  for (int a = 0; a < 5; ++a) {
    glEnableVertexAttribArray(a);
    glVertexAttribPointer(a, sizes[a], GL_FLOAT, GL_FALSE, 14 * sizeof(float), reinterpret_cast<void*>(offset * sizeof(float)));
    offset += sizes[a];
  }
  glBindVertexArray(0);
  // Textures: repeat, trilinear mipmaps (rows bottom first: v = 0 at the image's bottom).
  auto upload = [](GLuint* id, GLenum internal, GLenum format, GLenum type, int w, int h, const void* data) {
    glGenTextures(1, id);
    glBindTexture(GL_TEXTURE_2D, *id);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, internal, w, h, 0, format, type, data);
    glGenerateMipmap(GL_TEXTURE_2D);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_REPEAT);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_REPEAT);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  };
  std::vector<uint8_t> rgb(m.albedo.pixels() * 3);
  for (int y = 0; y < m.albedo.height; ++y)
    for (int x = 0; x < m.albedo.width; ++x)
      for (int c = 0; c < 3; ++c) rgb[(static_cast<size_t>(y) * m.albedo.width + x) * 3 + c] = m.albedo.at(x, m.albedo.height - 1 - y, c);
  upload(&g.albedo, GL_RGB8, GL_RGB, GL_UNSIGNED_BYTE, m.albedo.width, m.albedo.height, rgb.data());
  std::vector<float> h(m.height.pixels());
  for (int y = 0; y < m.height.height; ++y)
    for (int x = 0; x < m.height.width; ++x) h[static_cast<size_t>(y) * m.height.width + x] = m.height.at(x, m.height.height - 1 - y, 0);
  upload(&g.height, GL_R32F, GL_RED, GL_FLOAT, m.height.width, m.height.height, h.data());
  if (GLenum e = glGetError(); e != GL_NO_ERROR) return fail(fmt::format("OpenGL error {:#x} while uploading the relief material", e));
  return r;
}

Result<Eigen::Matrix4f> off_axis_view_projection(const Eigen::Vector3d& eye, const Screen& screen, double n, double f) {
  if (auto v = screen.validate(); !v) return std::unexpected(v.error());
  const Eigen::Vector3d xh = screen.right.normalized(), yh = -screen.down.normalized(), zh = xh.cross(yh);
  const Eigen::Vector3d rel = screen.corner - eye;
  const double dist = -rel.dot(zh);
  if (!(dist > 0)) return fail("the eye is on or behind the screen's plane");
  if (!(n > 0) || !(f > n)) return fail("needs 0 < near < far");
  const double k = n / dist;
  const double l = rel.dot(xh) * k, r = (rel.dot(xh) + screen.right.norm()) * k, t = rel.dot(yh) * k,
               b = (rel.dot(yh) - screen.down.norm()) * k;
  Eigen::Matrix4d proj = Eigen::Matrix4d::Zero();
  proj(0, 0) = 2 * n / (r - l);
  proj(0, 2) = (r + l) / (r - l);
  proj(1, 1) = 2 * n / (t - b);
  proj(1, 2) = (t + b) / (t - b);
  proj(2, 2) = -(f + n) / (f - n);
  proj(2, 3) = -2 * f * n / (f - n);
  proj(3, 2) = -1;
  Eigen::Matrix4d view = Eigen::Matrix4d::Identity();
  view.block<1, 3>(0, 0) = xh.transpose();
  view.block<1, 3>(1, 0) = yh.transpose();
  view.block<1, 3>(2, 0) = zh.transpose();
  view.block<3, 1>(0, 3) = -view.block<3, 3>(0, 0) * eye;
  return Eigen::Matrix4f((proj * view).cast<float>());
}

double screen_distance(const Eigen::Vector3d& eye, const Screen& screen) {
  const Eigen::Vector3d zh = screen.right.normalized().cross(-screen.down.normalized());
  return -(screen.corner - eye).dot(zh);
}

Result<MaterialDrawStats> MaterialRenderer::draw(const Eigen::Vector3d& eye, const Screen& screen, const Framebuffer& target,
                                                 const MaterialDrawOptions& o) {
  if (screen.width != target.width() || screen.height != target.height()) return fail("the screen and the target differ in size");
  const auto start = std::chrono::steady_clock::now();
  target.bind();
  target.clear(0.5f, 0.6f, 0.75f);
  auto st = draw_into_bound(eye, screen, std::min(0.01, 0.5 * screen_distance(eye, screen)), 1000, o);
  if (!st) return st;
  glFinish();
  st->frame_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return st;
}

Result<MaterialDrawStats> MaterialRenderer::draw_into_bound(const Eigen::Vector3d& eye, const Screen& screen, double near_m,
                                                            double far_m, const MaterialDrawOptions& o) {
  if (!(o.far_m > o.near_m) || !(o.blend >= 0) || o.pom_min_layers < 1 || o.pom_max_layers < o.pom_min_layers)
    return fail("material LOD: needs far > near, blend >= 0 and 1 <= min layers <= max layers");
  auto matrix = off_axis_view_projection(eye, screen, near_m, far_m);
  if (!matrix) return std::unexpected(matrix.error());
  const Eigen::Matrix4f vp = *matrix;
  Gpu& g = *gpu_;
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glUseProgram(g.program.id());
  const GlProgram& p = g.program;
  glUniformMatrix4fv(p.uniform("view_proj"), 1, GL_FALSE, vp.data());
  const Eigen::Vector3f e = eye.cast<float>();
  glUniform3fv(p.uniform("eye"), 1, e.data());
  glUniform3fv(p.uniform("light_dir"), 1, o.light_dir.data());
  glUniform1f(p.uniform("repeats"), repeats_);
  glUniform1f(p.uniform("depth"), depth_);
  glUniform1f(p.uniform("threshold"), static_cast<float>(threshold_));
  glUniform1f(p.uniform("blend"), static_cast<float>(o.blend));
  glUniform1f(p.uniform("vnear"), static_cast<float>(o.near_m));
  glUniform1f(p.uniform("vfar"), static_cast<float>(o.far_m));
  glUniform1i(p.uniform("method"), static_cast<int>(o.method));
  glUniform1i(p.uniform("flat_material"), flat_ ? 1 : 0);
  glUniform1i(p.uniform("min_layers"), o.pom_min_layers);
  glUniform1i(p.uniform("max_layers"), o.pom_max_layers);
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, g.albedo);
  glUniform1i(p.uniform("albedo"), 0);
  glActiveTexture(GL_TEXTURE1);
  glBindTexture(GL_TEXTURE_2D, g.height);
  glUniform1i(p.uniform("height"), 1);
  glBindVertexArray(g.vao);
  glDrawArrays(GL_TRIANGLES, 0, g.vertices);
  glBindVertexArray(0);
  glActiveTexture(GL_TEXTURE0);
  MaterialDrawStats st;
  st.threshold = threshold_;
  if (GLenum err = glGetError(); err != GL_NO_ERROR) return fail(fmt::format("OpenGL error {:#x} while drawing the relief", err));
  return st;
}

namespace {

// A quad as two triangles with its own vertices, normal and uvs.
void add_quad(RtMesh& m, const Eigen::Vector3f& o, const Eigen::Vector3f& u, const Eigen::Vector3f& v, float uv_u, float uv_v) {
  const int base = static_cast<int>(m.vertices.size());
  const Eigen::Vector3f n = u.cross(v).normalized();
  m.vertices.insert(m.vertices.end(), {o, o + u, o + u + v, o + v});
  m.normals.insert(m.normals.end(), {n, n, n, n});
  m.uvs.insert(m.uvs.end(), {{0, 0}, {uv_u, 0}, {uv_u, uv_v}, {0, uv_v}});
  if (m.levels.empty()) m.levels.emplace_back();
  m.levels[0].emplace_back(base, base + 1, base + 2);
  m.levels[0].emplace_back(base, base + 2, base + 3);
}

}  // namespace

MaterialScene material_board_scene(int width, int height) {
  MaterialScene s;
  // A 4 m wide, 30 m long board on the ground, seen from 1.6 m up looking along it.
  add_quad(s.mesh, {-2, 0, 0}, {4, 0, 0}, {0, 0, -30}, 1, 7.5f);
  s.eye = {0, 1.6, 0.5};
  s.screen = Screen::pinhole(s.eye, Eigen::Vector3d(0, -0.35, -1).normalized(), Eigen::Vector3d::UnitY(), 50, width, height);
  return s;
}

MaterialScene material_roof_scene(int width, int height) {
  MaterialScene s;
  // Rows of gabled roofs (ridges along x, 35 degree pitch) receding from the
  // eye: many faces at many angles and distances.
  const float pitch = 35.f * static_cast<float>(M_PI) / 180.f, half = 1.2f, rise = half * std::tan(pitch), len = 2.4f;
  for (int row = 0; row < 7; ++row)
    for (int col = -2; col <= 2; ++col) {
      const float x = col * (len + 0.4f) - len / 2, z = -1.2f - row * 3.2f, y = 0.2f * ((row + col + 6) % 3);
      const Eigen::Vector3f ridge(x, y + rise, z);
      // front slope (towards +z) and back slope
      add_quad(s.mesh, ridge + Eigen::Vector3f(0, -rise, half), {len, 0, 0}, {0, rise, -half}, 1, 1);
      add_quad(s.mesh, ridge, {len, 0, 0}, {0, -rise, -half}, 1, 1);
    }
  s.eye = {0.3, 2.4, 0.4};
  s.screen = Screen::pinhole(s.eye, Eigen::Vector3d(0, -0.45, -1).normalized(), Eigen::Vector3d::UnitY(), 55, width, height);
  return s;
}

}  // namespace s2r
