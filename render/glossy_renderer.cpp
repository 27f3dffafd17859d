#include "render/glossy_renderer.h"

#include <epoxy/gl.h>

#include <chrono>
#include <algorithm>
#include <cmath>
#include <limits>

#include <spdlog/fmt/fmt.h>

#include "core/image_io.h"
#include "core/report.h"
#include "render/gl_context.h"
#include "render/gl_program.h"
#include "trace/meshes.h"

namespace s2r {

namespace {

const char* kGlossyVertex = R"(#version 430 core
layout(location = 0) in vec3 pos;
layout(location = 1) in vec3 nrm;
layout(location = 2) in vec2 tex;
uniform mat4 view_proj;
out vec3 wpos;
out vec3 wnrm;
out vec2 uv;
void main() {
  wpos = pos;
  wnrm = nrm;
  uv = tex;
  gl_Position = view_proj * vec4(pos, 1.0);
}
)";

const char* kGlossyFragment = R"(#version 430 core
in vec3 wpos;
in vec3 wnrm;
in vec2 uv;
out vec4 colour;
uniform vec3 eye;
uniform sampler3D envmap;
uniform sampler2D roughness_map;
uniform int has_envmap;
uniform int has_roughness_map;
uniform float lambda_const;   // from the material's exponent
uniform float env_size;       // s
uniform float level_ratio;    // log(I) / log(256)
uniform float kd, kg;
uniform vec3 albedo;
uniform vec3 ambient_colour;  // diffuse light without a map
uniform mat3 env_from_world;
// log1p and expm1 without the cancellation of log(1 + y), exp(y) - 1 at small y.
float log1p_(float y) { return y < 1e-3 ? y * (1.0 - 0.5 * y) : log(1.0 + y); }
float expm1_(float y) { return y < 1e-3 ? y * (1.0 + 0.5 * y) : exp(y) - 1.0; }
// Roughness -> the map's radius for the exponent roughness_to_exponent(rho)
// (= g(1 - rho) of a 128^3, 256-level map): solve g_s,I(lambda) = g_128,256(1 - rho).
float lambda_for(float rho) {
  float a = 1.0 - clamp(rho, 0.0, 1.0);
  if (a <= 0.0) return 0.0;
  if (abs(level_ratio - 1.0) < 1e-6) return min(1.0, a * 128.0 / env_size);
  float x = 2.0 / (a * 128.0);
  float xs2 = expm1_(level_ratio * log1p_(x * x));
  return min(1.0, 2.0 / (env_size * sqrt(xs2)));
}
vec3 env(vec3 t) { return texture(envmap, (env_from_world * t) * 0.5 + 0.5).rgb; }
void main() {
  vec3 v = normalize(wpos - eye);
  vec3 ng = normalize(cross(dFdx(wpos), dFdy(wpos)));
  if (dot(ng, v) > 0.0) ng = -ng;  // faces the incoming ray
  vec3 n = normalize(wnrm);
  if (!(dot(n, n) > 0.0)) n = ng;
  if (dot(n, ng) < 0.0) n = -n;
  vec3 c = vec3(0.0);
  if (has_envmap != 0) {
    vec3 r = normalize(v - 2.0 * dot(v, n) * n);
    float lambda = has_roughness_map != 0 ? lambda_for(texture(roughness_map, uv).r) : lambda_const;
    c = (1.0 - kg) * kd * albedo * env(n * (1.0 / env_size)) + kg * env(r * lambda);
  } else {
    c = kd * albedo * ambient_colour;
  }
  colour = vec4(clamp(c, 0.0, 1.0), 1.0);
}
)";

// The backdrop: every pixel's ray through the screen, the panorama's nearest pixel.
const char* kBackdropVertex = R"(#version 430 core
void main() {
  vec2 p = vec2((gl_VertexID == 1) ? 3.0 : -1.0, (gl_VertexID == 2) ? 3.0 : -1.0);
  gl_Position = vec4(p, 1.0, 1.0);
}
)";

const char* kBackdropFragment = R"(#version 430 core
out vec4 colour;
uniform vec3 eye, corner, right_v, down_v;
uniform vec2 size;
uniform sampler2D panorama;
uniform int has_panorama;
uniform vec3 background;
uniform mat3 env_from_world;
const float PI = 3.14159265358979;
void main() {
  vec2 px = vec2(gl_FragCoord.x, size.y - gl_FragCoord.y);  // (x + 0.5, y + 0.5), rows top first
  vec3 d = normalize(env_from_world * (corner + px.x / size.x * right_v + px.y / size.y * down_v - eye));
  vec3 c = background;
  if (has_panorama != 0) {
    ivec2 wh = textureSize(panorama, 0);
    float phi = atan(d.x, -d.z);
    float theta = asin(clamp(d.y, -1.0, 1.0));
    int x = clamp(int(floor((phi + PI) / (2.0 * PI) * float(wh.x))), 0, wh.x - 1);
    int y = clamp(int(floor((PI / 2.0 - theta) / PI * float(wh.y))), 0, wh.y - 1);
    c = texelFetch(panorama, ivec2(x, wh.y - 1 - y), 0).rgb;  // uploaded bottom row first
  }
  colour = vec4(clamp(c, 0.0, 1.0), 0.0);
}
)";

struct DrawItem {
  GLuint vao = 0, vbo = 0, ibo = 0;
  GLsizei indices = 0;
  RtMaterial material;
  GLuint roughness = 0;  // 2D texture, 0: none
};

}  // namespace

struct GlossyRenderer::Gpu {
  GlProgram mesh, backdrop;
  std::vector<DrawItem> items;
  std::vector<GLuint> textures;  // roughness textures, one per scene texture used
  GLuint envmap = 0, panorama = 0;
  std::shared_ptr<const EnvironmentMap> map;
  Eigen::Vector3f background{0, 0, 0};
  Gpu(GlProgram m, GlProgram b) : mesh(std::move(m)), backdrop(std::move(b)) {}
  ~Gpu() {
    for (auto& it : items) {
      glDeleteVertexArrays(1, &it.vao);
      glDeleteBuffers(1, &it.vbo);
      glDeleteBuffers(1, &it.ibo);
    }
    if (!textures.empty()) glDeleteTextures(static_cast<GLsizei>(textures.size()), textures.data());
    if (envmap) glDeleteTextures(1, &envmap);
    if (panorama) glDeleteTextures(1, &panorama);
  }
};

bool scene_is_glossy(const RtScene& scene) {
  for (const auto& o : scene.objects)
    if (o.material.glossy > 0) return true;
  return false;
}

GlossyRenderer::~GlossyRenderer() = default;

Result<std::unique_ptr<GlossyRenderer>> GlossyRenderer::create(const RtScene& scene, std::shared_ptr<const EnvironmentMap> map) {
  auto mesh = GlProgram::build(kGlossyVertex, kGlossyFragment);
  if (!mesh) return std::unexpected(mesh.error());
  auto backdrop = GlProgram::build(kBackdropVertex, kBackdropFragment);
  if (!backdrop) return std::unexpected(backdrop.error());
  std::unique_ptr<GlossyRenderer> r(new GlossyRenderer);
  r->gpu_ = std::make_unique<Gpu>(std::move(*mesh), std::move(*backdrop));
  Gpu& g = *r->gpu_;
  g.background = scene.background;
  r->needs_envmap_ = scene_is_glossy(scene);
  if (r->needs_envmap_) {
    if (!map) return fail("a glossy material needs an environment map (s2r envmap)");
    g.map = map;
    const int s = map->size();
    // Half floats: half the memory of float at 1/2048 relative precision.
    glGenTextures(1, &g.envmap);
    glBindTexture(GL_TEXTURE_3D, g.envmap);
    glTexImage3D(GL_TEXTURE_3D, 0, GL_RGB16F, s, s, s, 0, GL_RGB, GL_FLOAT, map->data().data());
    for (GLenum p : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTexParameteri(GL_TEXTURE_3D, p, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    r->envmap_bytes_ = static_cast<size_t>(s) * s * s * 6;
  }
  if (scene.environment) {
    const ImageF& p = scene.environment->rgb();
    std::vector<float> flipped(p.data.size());
    const size_t row = static_cast<size_t>(p.width) * 3;
    for (int y = 0; y < p.height; ++y)
      std::copy_n(p.data.begin() + static_cast<std::ptrdiff_t>((p.height - 1 - y) * row), row, flipped.begin() + static_cast<std::ptrdiff_t>(y * row));
    glGenTextures(1, &g.panorama);
    glBindTexture(GL_TEXTURE_2D, g.panorama);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB32F, p.width, p.height, 0, GL_RGB, GL_FLOAT, flipped.data());
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  }
  std::vector<GLuint> texture_of(scene.textures.size(), 0);
  for (const RtObject& o : scene.objects) {
    const RtMesh& m = o.mesh;
    if (auto v = m.validate(o.name); !v) return std::unexpected(v.error());
    const int rt = o.material.roughness_texture;
    if (rt >= static_cast<int>(scene.textures.size())) return fail("object '" + o.name + "': roughness texture index out of range");
    if (rt >= 0 && m.uvs.empty()) return fail("object '" + o.name + "': a roughness texture needs uvs");
    DrawItem it;
    it.material = o.material;
    if (rt >= 0) {
      if (!texture_of[rt]) {
        const ImageU8& img = scene.textures[rt];
        std::vector<uint8_t> red(img.pixels());
        for (int y = 0; y < img.height; ++y)  // bottom row first: v = 0 at the image's bottom, as the ray tracer reads it
          for (int x = 0; x < img.width; ++x) red[static_cast<size_t>(y) * img.width + x] = img.at(x, img.height - 1 - y, 0);
        GLuint t = 0;
        glGenTextures(1, &t);
        glBindTexture(GL_TEXTURE_2D, t);
        glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
        glTexImage2D(GL_TEXTURE_2D, 0, GL_R8, img.width, img.height, 0, GL_RED, GL_UNSIGNED_BYTE, red.data());
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_REPEAT);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_REPEAT);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        g.textures.push_back(t);
        texture_of[rt] = t;
      }
      it.roughness = texture_of[rt];
    }
    // World-space vertices: position, normal, uv (8 floats).
    const Eigen::Isometry3f xf = o.world_from_object.cast<float>();
    const Eigen::Matrix3f nm = xf.linear().inverse().transpose();
    std::vector<float> vb;
    vb.reserve(m.vertices.size() * 8);
    for (size_t i = 0; i < m.vertices.size(); ++i) {
      const Eigen::Vector3f p = xf * m.vertices[i];
      const Eigen::Vector3f n = m.normals.empty() ? Eigen::Vector3f::Zero() : Eigen::Vector3f(nm * m.normals[i]);
      const Eigen::Vector2f t = m.uvs.empty() ? Eigen::Vector2f::Zero() : m.uvs[i];
      vb.insert(vb.end(), {p.x(), p.y(), p.z(), n.x(), n.y(), n.z(), t.x(), t.y()});
      r->bounds_.extend(p.cast<double>());
    }
    const auto& tris = m.levels.front();
    glGenVertexArrays(1, &it.vao);
    glBindVertexArray(it.vao);
    glGenBuffers(1, &it.vbo);
    glBindBuffer(GL_ARRAY_BUFFER, it.vbo);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(vb.size() * sizeof(float)), vb.data(), GL_STATIC_DRAW);
    glGenBuffers(1, &it.ibo);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, it.ibo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(tris.size() * sizeof(Eigen::Vector3i)), tris.data(), GL_STATIC_DRAW);
    for (int a = 0; a < 3; ++a) glEnableVertexAttribArray(a);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 8 * sizeof(float), nullptr);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 8 * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
    glVertexAttribPointer(2, 2, GL_FLOAT, GL_FALSE, 8 * sizeof(float), reinterpret_cast<void*>(6 * sizeof(float)));
    glBindVertexArray(0);
    it.indices = static_cast<GLsizei>(tris.size() * 3);
    r->triangles_ += tris.size();
    g.items.push_back(it);
  }
  if (GLenum e = glGetError(); e != GL_NO_ERROR) return fail(fmt::format("OpenGL error {:#x} while uploading the glossy scene", e));
  return r;
}

Result<GlossyDrawStats> GlossyRenderer::draw(const Eigen::Vector3d& eye, const Screen& screen, const Framebuffer& target) {
  if (screen.width != target.width() || screen.height != target.height())
    return fail(fmt::format("screen is {}x{} but the target is {}x{}", screen.width, screen.height, target.width(), target.height()));
  const auto start = std::chrono::steady_clock::now();
  target.bind();
  target.clear(gpu_->background.x(), gpu_->background.y(), gpu_->background.z());
  double far_m = 1000;
  if (!bounds_.isEmpty())
    for (int c = 0; c < 8; ++c) far_m = std::max(far_m, 2 * (bounds_.corner(Eigen::AlignedBox3d::CornerType(c)) - eye).norm());
  auto st = draw_into_bound(eye, screen, 0, far_m);
  if (!st) return st;
  glFinish();
  st->frame_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return st;
}

Screen screen_for_view(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera) {
  const Eigen::Matrix3d R = world_from_camera.linear();
  Screen s;
  s.name = "view";
  s.width = K.width;
  s.height = K.height;
  s.corner = world_from_camera.translation() + R * Eigen::Vector3d((-0.5 - K.cx) / K.fx, (-0.5 - K.cy) / K.fy, 1);
  s.right = R * Eigen::Vector3d(K.width / K.fx, 0, 0);
  s.down = R * Eigen::Vector3d(0, K.height / K.fy, 0);
  return s;
}

Result<GlossyDrawStats> GlossyRenderer::draw_into_bound(const Eigen::Vector3d& eye, const Screen& screen, double near_req, double far_m) {
  if (auto v = screen.validate(); !v) return std::unexpected(v.error());
  const double near_m = near_req > 0 ? near_req : std::min(0.01, 0.5 * screen_distance(eye, screen));
  auto matrix = off_axis_view_projection(eye, screen, near_m, far_m);
  if (!matrix) return std::unexpected(matrix.error());
  const Eigen::Matrix4f vp = *matrix;

  Gpu& g = *gpu_;
  const auto start = std::chrono::steady_clock::now();
  const Eigen::Matrix3f env_rot = env_from_world_.cast<float>();
  glDisable(GL_DEPTH_TEST);
  glUseProgram(g.backdrop.id());
  const Eigen::Vector3f e = eye.cast<float>(), c = screen.corner.cast<float>(), rv = screen.right.cast<float>(),
                        dv = screen.down.cast<float>();
  glUniform3fv(g.backdrop.uniform("eye"), 1, e.data());
  glUniform3fv(g.backdrop.uniform("corner"), 1, c.data());
  glUniform3fv(g.backdrop.uniform("right_v"), 1, rv.data());
  glUniform3fv(g.backdrop.uniform("down_v"), 1, dv.data());
  glUniform2f(g.backdrop.uniform("size"), static_cast<float>(screen.width), static_cast<float>(screen.height));
  glUniform3fv(g.backdrop.uniform("background"), 1, g.background.data());
  glUniform1i(g.backdrop.uniform("has_panorama"), g.panorama ? 1 : 0);
  glUniformMatrix3fv(g.backdrop.uniform("env_from_world"), 1, GL_FALSE, env_rot.data());
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, g.panorama);
  glUniform1i(g.backdrop.uniform("panorama"), 0);
  GLuint empty_vao = 0;
  glGenVertexArrays(1, &empty_vao);
  glBindVertexArray(empty_vao);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glDeleteVertexArrays(1, &empty_vao);

  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glUseProgram(g.mesh.id());
  glUniformMatrix4fv(g.mesh.uniform("view_proj"), 1, GL_FALSE, vp.data());
  glUniform3fv(g.mesh.uniform("eye"), 1, e.data());
  glUniform1i(g.mesh.uniform("has_envmap"), g.envmap ? 1 : 0);
  glUniformMatrix3fv(g.mesh.uniform("env_from_world"), 1, GL_FALSE, env_rot.data());
  const float s = g.map ? static_cast<float>(g.map->size()) : 1.f;
  glUniform1f(g.mesh.uniform("env_size"), s);
  glUniform1f(g.mesh.uniform("level_ratio"), g.map ? static_cast<float>(std::log(g.map->intensity_levels()) / std::log(256.0)) : 1.f);
  const Eigen::Vector3f ambient(1, 1, 1);
  glUniform3fv(g.mesh.uniform("ambient_colour"), 1, ambient.data());
  if (g.envmap) {
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_3D, g.envmap);
    glUniform1i(g.mesh.uniform("envmap"), 1);
  }
  glUniform1i(g.mesh.uniform("roughness_map"), 2);
  for (const DrawItem& it : g.items) {
    const RtMaterial& m = it.material;
    glUniform1f(g.mesh.uniform("kd"), 1.f);
    glUniform1f(g.mesh.uniform("kg"), m.glossy);
    glUniform3fv(g.mesh.uniform("albedo"), 1, m.diffuse.data());
    glUniform1f(g.mesh.uniform("lambda_const"),
                g.map ? static_cast<float>(envmap_radius(m.glossy_exponent, g.map->size(), g.map->intensity_levels())) : 0.f);
    glUniform1i(g.mesh.uniform("has_roughness_map"), it.roughness ? 1 : 0);
    glActiveTexture(GL_TEXTURE2);
    glBindTexture(GL_TEXTURE_2D, it.roughness);
    glBindVertexArray(it.vao);
    glDrawElements(GL_TRIANGLES, it.indices, GL_UNSIGNED_INT, nullptr);
  }
  glBindVertexArray(0);
  glActiveTexture(GL_TEXTURE0);
  if (relief_) {
    auto rs = relief_->draw_into_bound(eye, screen, near_m, far_m, relief_options_);
    if (!rs) return std::unexpected(with_context(rs.error(), "relief floor"));
  }
  GlossyDrawStats st;
  st.frame_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  st.envmap_bound = g.envmap != 0;
  st.envmap_texture_bytes = envmap_bytes_;
  st.triangles = triangles_;
  if (GLenum err = glGetError(); err != GL_NO_ERROR) return fail(fmt::format("OpenGL error {:#x} while drawing", err));
  return st;
}

}  // namespace s2r

namespace s2r {

ImageU8 roughness_ramps(int bands) {
  const int per = 32;
  ImageU8 r(4, per * std::max(1, bands), 3);
  for (int y = 0; y < r.height; ++y)
    for (int x = 0; x < r.width; ++x)
      for (int c = 0; c < 3; ++c) r.at(x, y, c) = static_cast<uint8_t>((y % per) * 255 / (per - 1));
  return r;
}

Result<GlossyComparison> compare_glossy_sphere(std::shared_ptr<const Panorama> pano, std::shared_ptr<const EnvironmentMap> map,
                                               const ImageU8& roughness, int size, int threads) {
  if (!pano || !map) return fail("glossy comparison needs a panorama and its environment map");
  if (roughness.empty()) return fail("glossy comparison needs a roughness texture");
  RtScene scene;
  scene.environment = pano;
  scene.textures.push_back(roughness);
  RtObject sphere;
  sphere.name = "glossy sphere";
  sphere.mesh = sphere_mesh(5);
  for (const auto& v : sphere.mesh.vertices)  // latitude only: no seam in v
    sphere.mesh.uvs.emplace_back(0.5f, 0.5f + std::asin(std::clamp(v.y(), -1.f, 1.f)) / static_cast<float>(M_PI));
  sphere.material.diffuse.setZero();
  sphere.material.specular.setZero();
  sphere.material.ambient = 0;
  sphere.material.glossy = 1;
  sphere.material.roughness_texture = 0;
  scene.objects.push_back(sphere);
  const Eigen::Vector3d eye(0, 0.6, 3.2);
  const Screen screen = Screen::pinhole(eye, -eye.normalized(), Eigen::Vector3d::UnitY(), 42, size, size);

  GlossyComparison out;
  {
    auto ctx = create_headless_context();
    if (!ctx) return std::unexpected(ctx.error());
    auto fb = Framebuffer::create(size, size);
    if (!fb) return std::unexpected(fb.error());
    auto gl = GlossyRenderer::create(scene, map);
    if (!gl) return std::unexpected(gl.error());
    auto warm = (*gl)->draw(eye, screen, *fb);
    if (!warm) return std::unexpected(warm.error());
    auto st = (*gl)->draw(eye, screen, *fb);
    if (!st) return std::unexpected(st.error());
    out.gl_frame_ms = st->frame_ms;
    out.envmap_texture_bytes = st->envmap_texture_bytes;
    out.gl = fb->read_rgb();
  }
  auto tracer = RayTracer::create(scene);
  if (!tracer) return std::unexpected(tracer.error());
  TraceOptions o;
  o.threads = threads;
  const auto start = std::chrono::steady_clock::now();
  out.traced = to_u8((*tracer)->render(screen, eye, o).color);
  out.trace_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  // The sphere's pixels and their view angle, analytically (unit sphere at 0),
  // leaving out a pixel's width at the silhouette where the mesh and the
  // sphere disagree about coverage.
  double sum = 0, grazing_sum = 0;
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const Eigen::Vector3d d = (screen.point(x, y) - eye).normalized();
      const double b = eye.dot(d), c = eye.squaredNorm() - 1, disc = b * b - c;
      if (disc <= 0) continue;
      const Eigen::Vector3d n = (eye + (-b - std::sqrt(disc)) * d).normalized();
      const double cos_view = -n.dot(d);
      if (cos_view < 0.08) continue;  // silhouette
      const bool grazing = cos_view < std::cos(75 * M_PI / 180);
      for (int ch = 0; ch < 3; ++ch) {
        const double e = std::abs(static_cast<int>(out.gl.at(x, y, ch)) - static_cast<int>(out.traced.at(x, y, ch)));
        sum += e;
        out.max_error = std::max(out.max_error, e);
        if (grazing) {
          grazing_sum += e;
          out.grazing_max_error = std::max(out.grazing_max_error, e);
        }
      }
      ++out.pixels;
      if (grazing) ++out.grazing_pixels;
    }
  out.mean_error = out.pixels ? sum / (3.0 * out.pixels) : 0;
  out.grazing_mean_error = out.grazing_pixels ? grazing_sum / (3.0 * out.grazing_pixels) : 0;
  return out;
}

}  // namespace s2r

namespace s2r {

Eigen::Matrix3d environment_from_world(const Eigen::Vector3d& up_in) {
  const Eigen::Vector3d up = up_in.normalized();
  Eigen::Vector3d a = Eigen::Vector3d::UnitX() - up.x() * up;
  if (a.norm() < 0.1) a = Eigen::Vector3d::UnitY() - up.y() * up;
  a.normalize();
  Eigen::Matrix3d R;
  R.row(0) = a.transpose();
  R.row(1) = up.transpose();
  R.row(2) = a.cross(up).transpose();
  return R;
}

void report_environment(const PreparedEnvironment& env, Report& rep) {
  rep.params["environment_map"] = env.envmap_source;
  if (env.map) {
    rep.counts["envmap_seconds"] = env.envmap_seconds;
    rep.counts["envmap_size"] = double(env.map->size());
  } else {
    rep.skipped["environment_map_not_needed_no_glossy_material"] = 1;
  }
  for (const auto& w : env.warnings) rep.warnings.push_back(w);
}

Result<PreparedEnvironment> prepare_environment(const EnvironmentSetup& setup, const Eigen::AlignedBox3d& bounds) {
  if (!setup.up.allFinite() || setup.up.norm() == 0) return fail("up: must be a finite non-zero direction");
  if (bounds.isEmpty()) return fail("the model has no extent to put a floor under");
  PreparedEnvironment out;
  RtScene scene;
  if (!setup.panorama.empty()) {
    auto pano = load_panorama(setup.panorama, setup.clamp, &out.warnings);
    if (!pano) return std::unexpected(pano.error());
    scene.environment = std::make_shared<const Panorama>(std::move(*pano));
  }
  const Eigen::Vector3d up = setup.up.normalized();
  const Eigen::Vector3d centre = bounds.center();
  const double radius = 0.5 * bounds.diagonal().norm();
  double lowest = std::numeric_limits<double>::infinity();
  for (int c = 0; c < 8; ++c) lowest = std::min(lowest, up.dot(bounds.corner(Eigen::AlignedBox3d::CornerType(c))));
  if (setup.floor_roughness > 1) return fail("floor roughness must be in [0, 1]");
  const bool relief = setup.floor_relief_R >= 0;
  RtMesh floor_mesh;
  if (setup.floor_roughness >= 0 || relief) {
    const Eigen::Matrix3d R = environment_from_world(up);
    const Eigen::Vector3d a = R.row(0).transpose(), b = R.row(2).transpose();
    const Eigen::Vector3d o = centre + (lowest - up.dot(centre)) * up;
    const double h = 3 * radius;
    const int n = 16;  // a grid, so per-vertex interpolation is not all the floor has
    const float tiles = 4.f;  // the roughness map, or the relief's pattern, 4 times per side
    for (int j = 0; j <= n; ++j)
      for (int i = 0; i <= n; ++i) {
        const double u = static_cast<double>(i) / n, v = static_cast<double>(j) / n;
        floor_mesh.vertices.push_back((o + (2 * u - 1) * h * a + (2 * v - 1) * h * b).cast<float>());
        floor_mesh.normals.push_back(up.cast<float>());
        floor_mesh.uvs.emplace_back(static_cast<float>(tiles * u), static_cast<float>(tiles * v));
      }
    std::vector<Eigen::Vector3i> tris;
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const int k = j * (n + 1) + i;
        tris.emplace_back(k, k + 1, k + n + 2);
        tris.emplace_back(k, k + n + 2, k + n + 1);
      }
    floor_mesh.levels = {tris};
  }
  if (setup.floor_roughness >= 0 && !relief) {
    RtObject floor;
    floor.name = "floor";
    floor.mesh = floor_mesh;
    floor.material.diffuse = setup.floor_colour;
    floor.material.glossy = setup.floor_glossy;
    floor.material.glossy_exponent = static_cast<float>(roughness_to_exponent(setup.floor_roughness));
    if (!setup.floor_roughness_texture.empty()) {
      auto tex = read_image_u8(setup.floor_roughness_texture);
      if (!tex) return std::unexpected(with_context(tex.error(), "floor roughness texture"));
      scene.textures.push_back(std::move(*tex));
      floor.material.roughness_texture = static_cast<int>(scene.textures.size()) - 1;
    }
    scene.objects.push_back(std::move(floor));
  }
  for (size_t i = 0; i < setup.props.size(); ++i) {
    const auto& p = setup.props[i];
    if (!p.centre.allFinite() || !(p.radius > 0) || !(p.roughness >= 0 && p.roughness <= 1))
      return fail(fmt::format("prop {}: needs a finite centre, a radius > 0 and a roughness in [0, 1]", i));
    RtObject s;
    s.name = fmt::format("sphere {}", i);
    s.mesh = sphere_mesh(4, p.centre, p.radius);
    s.material.diffuse = {0.8f, 0.8f, 0.8f};
    s.material.glossy = 1;
    s.material.glossy_exponent = static_cast<float>(roughness_to_exponent(p.roughness));
    scene.objects.push_back(std::move(s));
  }
  std::shared_ptr<const EnvironmentMap> map;
  Stopwatch clock;
  if (!scene_is_glossy(scene)) {
    out.envmap_source = "not needed";
  } else if (!setup.envmap.empty()) {
    auto m = EnvironmentMap::load(setup.envmap);
    if (!m) return std::unexpected(m.error());
    map = std::make_shared<const EnvironmentMap>(std::move(*m));
    out.envmap_source = "loaded";
  } else {
    if (!scene.environment) return fail("panorama: a glossy floor or prop needs a panorama (or a prebuilt environment map)");
    auto m = build_envmap(*scene.environment, setup.envmap_options);
    if (!m) return std::unexpected(m.error());
    map = std::make_shared<const EnvironmentMap>(std::move(*m));
    out.envmap_source = "built";
  }
  out.envmap_seconds = clock.seconds();
  auto r = GlossyRenderer::create(scene, map);
  if (!r) return std::unexpected(r.error());
  (*r)->set_environment_from_world(environment_from_world(up));
  if (relief) {
    const double Rn = std::clamp(setup.floor_relief_R, 0.0, 1000.0), Dn = std::clamp(setup.floor_relief_D, 0.0, 1000.0);
    auto material = MaterialRenderer::create(floor_mesh, brick_material(256, 2 + Rn / 1000 * 8, Dn / 1000 * 0.1));
    if (!material) return std::unexpected(with_context(material.error(), "relief floor"));
    MaterialDrawOptions mo;
    mo.near_m = 0;
    mo.far_m = 12 * radius;  // V: 0 at the eye, 1000 at the far edge of the floor seen from nearby
    Eigen::AlignedBox3d box;
    for (const auto& v : floor_mesh.vertices) box.extend(v.cast<double>());
    (*r)->set_relief(std::move(*material), mo, box);
  }
  out.renderer = std::move(*r);
  out.map = map;
  return out;
}

}  // namespace s2r
