#include "trace/raytracer.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>

#include <embree3/rtcore.h>
#include <meshoptimizer.h>
#include <spdlog/fmt/fmt.h>

#include "core/parallel.h"
#include "core/report.h"

namespace s2r {

using Eigen::Vector3d;
using Eigen::Vector3f;
using Eigen::Vector3i;

Status RtMesh::validate(const std::string& what) const {
  if (vertices.empty() || levels.empty() || levels[0].empty()) return fail(what + ": mesh has no triangles");
  for (const auto& v : vertices)
    if (!v.allFinite()) return fail(what + ": a vertex is not finite");
  if (!normals.empty() && normals.size() != vertices.size()) return fail(what + ": normals and vertices differ in count");
  if (!colors.empty() && colors.size() != vertices.size()) return fail(what + ": colours and vertices differ in count");
  if (!uvs.empty() && uvs.size() != vertices.size()) return fail(what + ": uvs and vertices differ in count");
  const int n = static_cast<int>(vertices.size());
  for (size_t k = 0; k < levels.size(); ++k) {
    if (levels[k].empty()) return fail(fmt::format("{}: level {} has no triangles", what, k));
    if (k > 0 && levels[k].size() >= levels[k - 1].size())
      return fail(fmt::format("{}: level {} is not coarser than level {}", what, k, k - 1));
    for (const auto& f : levels[k])
      if ((f.array() < 0).any() || (f.array() >= n).any())
        return fail(fmt::format("{}: level {} indexes a vertex out of range", what, k));
  }
  return {};
}

Status RtCurves::validate() const {
  if (points.empty() || segments.empty()) return fail("curves '" + name + "': no segments");
  for (const auto& p : points)
    if (!p.allFinite() || !(p.w() > 0)) return fail("curves '" + name + "': a point is not finite or its radius is not positive");
  for (uint32_t s : segments)
    if (static_cast<size_t>(s) + 1 >= points.size())
      return fail(fmt::format("curves '{}': segment {} runs past the last point", name, s));
  if (!colors.empty() && colors.size() != segments.size())
    return fail("curves '" + name + "': colours and segments differ in count");
  for (const auto& c : colors)
    if (!c.allFinite()) return fail("curves '" + name + "': a colour is not finite");
  if (material.texture >= 0 || material.roughness_texture >= 0)
    return fail("curves '" + name + "': curves have no uvs for a texture");
  return {};
}

Result<std::vector<std::vector<Vector3i>>> build_lod_chain(const std::vector<Vector3f>& vertices,
                                                           const std::vector<Vector3i>& faces, size_t n_min, int count) {
  if (faces.empty()) return fail("cannot simplify a mesh without triangles");
  if (count < 1) return fail("the level count must be at least 1");
  std::vector<std::vector<Vector3i>> chain{faces};
  const size_t n_max = faces.size();
  n_min = std::clamp<size_t>(n_min, 1, n_max);
  std::vector<unsigned> in(faces.size() * 3), out(faces.size() * 3);
  std::memcpy(in.data(), faces.data(), in.size() * sizeof(unsigned));
  for (int k = 1; k < count; ++k) {
    // Geometric steps from N_max to N_min.
    const double t = static_cast<double>(k) / (count - 1);
    const size_t target = static_cast<size_t>(std::llround(n_max * std::pow(double(n_min) / n_max, t)));
    if (target >= chain.back().size()) continue;
    // From the full mesh each time, so the levels do not compound errors.
    size_t n = meshopt_simplify(out.data(), in.data(), in.size(), vertices[0].data(), vertices.size(), sizeof(Vector3f),
                                target * 3, 1.0f, 0, nullptr);
    // Topology can stop the edge collapses short; the sloppy simplifier does not preserve it and reaches the target.
    if (n / 3 > target + target / 4)
      n = meshopt_simplifySloppy(out.data(), in.data(), in.size(), vertices[0].data(), vertices.size(), sizeof(Vector3f),
                                 target * 3, 1.0f, nullptr);
    if (n == 0 || n / 3 >= chain.back().size()) continue;
    std::vector<Vector3i> level(n / 3);
    std::memcpy(static_cast<void*>(level.data()), out.data(), n * sizeof(unsigned));
    chain.push_back(std::move(level));
  }
  return chain;
}

Screen Screen::pinhole(const Vector3d& eye, const Vector3d& forward, const Vector3d& up, double fov_y_deg, int width,
                       int height) {
  Screen s;
  s.name = "view";
  s.width = width;
  s.height = height;
  const Vector3d f = forward.normalized();
  Vector3d r = f.cross(up);
  if (r.norm() < 1e-9) r = f.cross(Vector3d::UnitZ());
  r.normalize();
  const Vector3d u = r.cross(f);
  const double half_h = std::tan(fov_y_deg * M_PI / 360.0);
  const double half_w = half_h * width / std::max(1, height);
  s.corner = eye + f - half_w * r + half_h * u;
  s.right = 2 * half_w * r;
  s.down = -2 * half_h * u;
  return s;
}

Status Screen::validate() const {
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384)
    return fail(fmt::format("screen '{}': size {}x{} is outside 1..16384", name, width, height));
  if (!corner.allFinite() || !right.allFinite() || !down.allFinite() || right.cross(down).norm() == 0)
    return fail(fmt::format("screen '{}': degenerate or non-finite plane", name));
  return {};
}

void TraceStats::add(const TraceStats& o) {
  pixels += o.pixels;
  outside_field += o.outside_field;
  central += o.central;
  primary += o.primary;
  secondary += o.secondary;
  shadow += o.shadow;
  depth_cut += o.depth_cut;
  total_internal += o.total_internal;
  misses += o.misses;
  empty_tiles_pixels += o.empty_tiles_pixels;
  glossy_lobes += o.glossy_lobes;
  for (size_t i = 0; i < rays_per_quantum.size(); ++i) rays_per_quantum[i] += o.rays_per_quantum[i];
}

ImageU8 to_u8(const ImageF& linear) {
  ImageU8 out(linear.width, linear.height, linear.channels);
  for (size_t i = 0; i < linear.data.size(); ++i) {
    const float v = linear.data[i];
    out.data[i] = static_cast<uint8_t>(std::lround(std::clamp(std::isfinite(v) ? v : 0.0f, 0.0f, 1.0f) * 255.0f));
  }
  return out;
}

Vector3f offset_ray_origin(const Vector3f& p, const Vector3f& n) {
  // Waechter and Binder: move by an integer number of ULPs proportional to
  // the normal, except near the origin where ULPs vanish and a fixed offset
  // takes over.
  constexpr float kOrigin = 1.0f / 32.0f, kFloatScale = 1.0f / 65536.0f, kIntScale = 256.0f;
  Vector3f out;
  for (int i = 0; i < 3; ++i) {
    const int of = static_cast<int>(kIntScale * n[i]);
    int32_t bits;
    std::memcpy(&bits, &p[i], 4);
    bits += p[i] < 0 ? -of : of;
    float moved;
    std::memcpy(&moved, &bits, 4);
    out[i] = std::abs(p[i]) < kOrigin ? p[i] + kFloatScale * n[i] : moved;
  }
  return out;
}

bool refract_dir(const Vector3f& d, const Vector3f& n, float eta, Vector3f* out) {
  const float cos_i = std::clamp(-d.dot(n), -1.0f, 1.0f);
  const float k = 1.0f - eta * eta * (1.0f - cos_i * cos_i);
  if (k < 0) return false;
  *out = (eta * d + (eta * cos_i - std::sqrt(k)) * n).normalized();
  return true;
}

namespace {

template <class T>
bool same_data(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(static_cast<const void*>(a.data()), static_cast<const void*>(b.data()),
                                                           a.size() * sizeof(T)) == 0);
}

bool same_mesh(const RtMesh& a, const RtMesh& b) {
  if (a.levels.size() != b.levels.size()) return false;
  for (size_t k = 0; k < a.levels.size(); ++k)
    if (!same_data(a.levels[k], b.levels[k])) return false;
  return same_data(a.vertices, b.vertices) && same_data(a.normals, b.normals) && same_data(a.colors, b.colors) &&
         same_data(a.uvs, b.uvs);
}

struct Hit {
  bool found = false;
  int object = -1;  // instance: objects first, then curves
  int prim = -1;
  float t = 0, u = 0, v = 0;
  Vector3f ng = Vector3f::Zero();  // Embree's, in the instance's frame (curves: the world)
};

// What one material needs checked, for objects and curves alike.
Status check_material(const std::string& what, const RtMaterial& m, const RtScene& scene, bool has_uvs) {
  if (m.reflect < 0 || m.transmit < 0 || m.glossy < 0 || m.reflect + m.transmit + m.glossy > 1)
    return fail(what + ": reflect, transmit and glossy must be >= 0 and sum to at most 1");
  if (m.glossy > 0 && !scene.environment) return fail(what + ": a glossy material needs an environment");
  if (!(m.glossy_exponent >= 0) || !std::isfinite(m.glossy_exponent))
    return fail(what + ": glossy exponent must be finite and >= 0");
  if (!(m.ior > 0) || !std::isfinite(m.ior)) return fail(what + ": index of refraction must be positive");
  if (!(m.shininess >= 0) || !std::isfinite(m.shininess)) return fail(what + ": shininess must be >= 0");
  if (!m.diffuse.allFinite() || !m.specular.allFinite() || !std::isfinite(m.ambient))
    return fail(what + ": diffuse, specular and ambient must be finite");
  if (m.texture >= static_cast<int>(scene.textures.size())) return fail(what + ": texture index out of range");
  if (m.texture >= 0 && !has_uvs) return fail(what + ": a texture needs uvs");
  if (m.roughness_texture >= static_cast<int>(scene.textures.size()) || (m.roughness_texture >= 0 && !has_uvs) ||
      (m.roughness_texture >= 0 && scene.textures[m.roughness_texture].empty()))
    return fail(what + ": the roughness texture must be a non-empty scene texture and the mesh needs uvs");
  if (m.texture >= 0 && scene.textures[m.texture].empty()) return fail(what + ": empty texture");
  return {};
}

}  // namespace

struct RayTracer::Impl {
  RtScene scene;
  RTCDevice device = nullptr;
  // Objects with the same mesh share its BVHs and shading data (instancing):
  // the working set stays one mesh's levels however many copies stand around.
  std::vector<std::vector<RTCScene>> mesh_levels;  // [unique mesh][level]
  std::vector<int> mesh_of;                         // object -> unique mesh
  std::vector<const RtMesh*> meshes;                // unique mesh -> its data
  std::vector<RTCScene> tops;                        // distinct level combinations
  std::vector<std::vector<int>> top_detail;          // [top][object] level used
  std::array<int, kQuanta + 1> quantum_top{};        // quantum -> top scene
  std::vector<Eigen::Matrix3f> normal_from_object;
  std::vector<RTCScene> curve_scenes;                // one per RtCurves, in every top scene
  Eigen::AlignedBox3f bounds;  // every object, slightly enlarged
  double build_seconds = 0;

  // The rays from `eye` through a rectangle of pixels fill the pyramid
  // spanned by its corner rays; when all eight box corners lie outside one of
  // its side planes, none of those rays can meet the box.
  bool tile_misses_bounds(const Vector3d& eye, const Vector3d (&c)[4]) const {
    if (bounds.isEmpty()) return true;
    const Vector3d mid = c[0] + c[1] + c[2] + c[3];
    const int ring[4] = {0, 1, 3, 2};  // corners in order around the rectangle
    for (int i = 0; i < 4; ++i) {
      Vector3d n = c[ring[i]].cross(c[ring[(i + 1) % 4]]);
      if (n.dot(mid) < 0) n = -n;
      bool all_out = true;
      for (int k = 0; k < 8 && all_out; ++k) {
        const Vector3d b = bounds.corner(static_cast<Eigen::AlignedBox3f::CornerType>(k)).cast<double>();
        all_out = n.dot(b - eye) < 0;
      }
      if (all_out) return true;
    }
    return false;
  }

  // Rays that miss the scene's box need no BVH traversal at all (on the
  // CAVE's empty screens that is most of them).
  bool misses_bounds(const Vector3f& o, const Vector3f& d) const {
    float t0 = 0, t1 = std::numeric_limits<float>::infinity();
    for (int i = 0; i < 3; ++i) {
      const float inv = 1.0f / d[i];
      float a = (bounds.min()[i] - o[i]) * inv, b = (bounds.max()[i] - o[i]) * inv;
      if (std::isnan(a) || std::isnan(b)) continue;  // d[i] = 0 with o on the slab plane: no constraint
      if (a > b) std::swap(a, b);
      t0 = std::max(t0, a);
      t1 = std::min(t1, b);
      if (t0 > t1) return true;
    }
    return false;
  }

  ~Impl() {
    for (auto s : tops) rtcReleaseScene(s);
    for (auto& v : mesh_levels)
      for (auto s : v) rtcReleaseScene(s);
    for (auto s : curve_scenes) rtcReleaseScene(s);
    if (device) rtcReleaseDevice(device);
  }

  std::vector<int> detail_for(double level) const {
    std::vector<int> d(scene.objects.size(), 0);
    for (size_t j = 0; j < scene.objects.size(); ++j) {
      const auto& lv = scene.objects[j].mesh.levels;
      const double n_max = static_cast<double>(lv.front().size()), n_min = static_cast<double>(lv.back().size());
      const double need = std::clamp(level, 0.0, 1.0) * (n_max - n_min) + n_min;  // eq. 10
      int k = 0;
      while (k + 1 < static_cast<int>(lv.size()) && static_cast<double>(lv[k + 1].size()) >= need) ++k;
      d[j] = k;
    }
    return d;
  }

  Vector3f trace_unit(const Vector3f& origin, const Vector3f& dir, float level, int reflect_max,
                      const std::vector<PointLight>& lights, TraceStats& st) const {
    const int q = quantum(level);
    ++st.primary;
    ++st.rays_per_quantum[q];
    // Reflect_i = level * Reflect_max (eq. 9), whole bounces.
    const int budget = static_cast<int>(std::floor(std::clamp(level, 0.0f, 1.0f) * std::max(0, reflect_max) + 1e-6f));
    return shade(quantum_top[q], origin, dir, 0, budget, lights, st);
  }

  static int quantum(double level) {
    return std::clamp(static_cast<int>(std::ceil(level * kQuanta - 1e-9)), 1, kQuanta);
  }

  Hit intersect(int top, const Vector3f& o, const Vector3f& d,
                float tfar = std::numeric_limits<float>::infinity()) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh;
    rh.ray.org_x = o.x(), rh.ray.org_y = o.y(), rh.ray.org_z = o.z();
    rh.ray.dir_x = d.x(), rh.ray.dir_y = d.y(), rh.ray.dir_z = d.z();
    rh.ray.tnear = 0;
    rh.ray.tfar = tfar;
    rh.ray.mask = 0xffffffffu;
    rh.ray.flags = 0;
    rh.ray.time = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(tops[top], &ctx, &rh);
    Hit h;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return h;
    h.found = true;
    h.object = static_cast<int>(rh.hit.instID[0]);
    h.prim = static_cast<int>(rh.hit.primID);
    h.t = rh.ray.tfar;
    h.u = rh.hit.u;
    h.v = rh.hit.v;
    h.ng = Vector3f(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
    return h;
  }

  bool occluded(int top, const Vector3f& o, const Vector3f& d, float tfar) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRay r;
    r.org_x = o.x(), r.org_y = o.y(), r.org_z = o.z();
    r.dir_x = d.x(), r.dir_y = d.y(), r.dir_z = d.z();
    r.tnear = 0;
    r.tfar = tfar;
    r.mask = 0xffffffffu;
    r.flags = 0;
    r.time = 0;
    rtcOccluded1(tops[top], &ctx, &r);
    return r.tfar < 0;
  }

  Vector3f texel(int texture, const Eigen::Vector2f& uv) const {
    const ImageU8& img = scene.textures[texture];
    // Repeat wrap, bilinear, (0, 0) at the bottom left.
    const float x = (uv.x() - std::floor(uv.x())) * img.width - 0.5f;
    const float y = (1.0f - (uv.y() - std::floor(uv.y()))) * img.height - 0.5f;
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    const float fx = x - x0, fy = y - y0;
    Vector3f c = Vector3f::Zero();
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const int xi = ((x0 + dx) % img.width + img.width) % img.width;
        const int yi = ((y0 + dy) % img.height + img.height) % img.height;
        const float w = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy);
        for (int ch = 0; ch < 3; ++ch) c[ch] += w * img.at(xi, yi, std::min(ch, img.channels - 1)) / 255.0f;
      }
    return c;
  }

  // The surface at a hit: unit geometric normal (world), shading normal,
  // colour before lighting, material, and the uv where there is one.
  struct Surface {
    Vector3f ng, ns, base;
    const RtMaterial* mat = nullptr;
    const RtMesh* mesh = nullptr;
    Vector3i face = Vector3i::Zero();
    float w0 = 0;
  };

  Vector3f geometric_normal(int top, const Hit& h) const {
    const int n_obj = static_cast<int>(scene.objects.size());
    if (h.object >= n_obj) return h.ng.normalized();
    const RtMesh& m = *meshes[mesh_of[h.object]];
    const Vector3i f = m.levels[top_detail[top][h.object]][h.prim];
    return (normal_from_object[h.object] * (m.vertices[f[1]] - m.vertices[f[0]]).cross(m.vertices[f[2]] - m.vertices[f[0]]))
        .normalized();
  }

  Surface surface(int top, const Hit& h, const Vector3f& p, const Vector3f& d) const {
    Surface s;
    s.ng = geometric_normal(top, h);
    if (!s.ng.allFinite()) s.ng = -d;
    const Vector3f nf = d.dot(s.ng) < 0 ? s.ng : Vector3f(-s.ng);  // faces the incoming ray
    s.ns = nf;
    const int n_obj = static_cast<int>(scene.objects.size());
    if (h.object >= n_obj) {
      const RtCurves& cv = scene.curves[h.object - n_obj];
      s.mat = &cv.material;
      s.base = cv.colors.empty() ? s.mat->diffuse : Vector3f(s.mat->diffuse.cwiseProduct(cv.colors[h.prim]));
    } else {
      const RtMesh& m = *meshes[mesh_of[h.object]];
      const Vector3i f = m.levels[top_detail[top][h.object]][h.prim];
      s.mesh = &m;
      s.face = f;
      s.w0 = 1 - h.u - h.v;
      if (!m.normals.empty()) {
        Vector3f n = normal_from_object[h.object] * (s.w0 * m.normals[f[0]] + h.u * m.normals[f[1]] + h.v * m.normals[f[2]]);
        if (n.squaredNorm() > 0) {
          n.normalize();
          s.ns = n.dot(nf) < 0 ? Vector3f(-n) : n;
        }
      }
      s.mat = &scene.objects[h.object].material;
      s.base = s.mat->diffuse;
      if (!m.colors.empty())
        s.base = s.base.cwiseProduct(s.w0 * m.colors[f[0]] + h.u * m.colors[f[1]] + h.v * m.colors[f[2]]);
      if (s.mat->texture >= 0) s.base = s.base.cwiseProduct(texel(s.mat->texture, uv(s, h)));
    }
    if (s.mat->albedo) s.base = s.base.cwiseProduct(s.mat->albedo(p, d));
    return s;
  }

  static Eigen::Vector2f uv(const Surface& s, const Hit& h) {
    const auto& t = s.mesh->uvs;
    return s.w0 * t[s.face[0]] + h.u * t[s.face[1]] + h.v * t[s.face[2]];
  }

  Vector3f shade(int top, const Vector3f& o, const Vector3f& d, int depth, int budget, const std::vector<PointLight>& lights,
                 TraceStats& st) const {
    const Hit h = misses_bounds(o, d) ? Hit{} : intersect(top, o, d);
    if (!h.found) {
      ++st.misses;
      return scene.environment ? scene.environment->lookup(d.cast<double>()) : scene.background;
    }
    const Vector3f p = o + h.t * d;
    const Surface sf = surface(top, h, p, d);
    const Vector3f& ng = sf.ng;
    const Vector3f& ns = sf.ns;
    const Vector3f& base = sf.base;
    const RtMaterial& mat = *sf.mat;
    const bool entering = d.dot(ng) < 0;
    const Vector3f nf = entering ? ng : Vector3f(-ng);  // faces the incoming ray

    Vector3f local = mat.ambient * base;
    const Vector3f lifted = offset_ray_origin(p, nf);
    for (const auto& light : lights) {
      Vector3f to_light = light.position.cast<float>();
      float dist = std::numeric_limits<float>::infinity();
      if (!light.directional) {
        to_light -= p;
        dist = to_light.norm();
      }
      const float len = light.directional ? to_light.norm() : dist;
      if (!(len > 0)) continue;
      to_light /= len;
      const float ndl = ns.dot(to_light);
      if (ndl <= 0 || nf.dot(to_light) <= 0) continue;
      if (light.shadows) {
        ++st.shadow;
        if (occluded(top, lifted, to_light, light.directional ? dist : dist * (1 - 1e-5f))) continue;
      }
      Vector3f c = base * ndl;
      const Vector3f r = 2 * ndl * ns - to_light;
      const float rv = -r.dot(d);
      // max(0, r.v)^s as exp(s log(r.v)): finite for any exponent, 0 at r.v <= 0.
      if (rv > 0 && mat.shininess > 0) c += mat.specular * std::exp(mat.shininess * std::log(std::min(rv, 1.0f)));
      local += c.cwiseProduct(light.intensity);
    }
    const float kr = mat.reflect, kt = mat.transmit, kg = mat.glossy;
    Vector3f out = std::max(0.0f, 1 - kr - kt - kg) * local;
    if (kg > 0) {
      ++st.glossy_lobes;
      const Vector3f r = (d - 2 * d.dot(ns) * ns).normalized();
      double exponent = mat.glossy_exponent;
      if (mat.roughness_texture >= 0)
        exponent = roughness_to_exponent(texel(mat.roughness_texture, uv(sf, h)).x());
      if (auto g = phong_lobe(*scene.environment, r.cast<double>(), exponent)) out += kg * g->cast<float>();
    }
    if (kr <= 0 && kt <= 0) return out;
    if (depth >= budget) {
      ++st.depth_cut;
      return out + (kr + kt) * scene.background;
    }
    const Vector3f refl = (d - 2 * d.dot(ns) * ns).normalized();
    Vector3f reflected = Vector3f::Zero();
    if (kr > 0 || kt > 0) {
      Vector3f trans;
      const bool refracts = kt > 0 && refract_dir(d, ns, entering ? 1.0f / mat.ior : mat.ior, &trans);
      if (kt > 0 && !refracts) ++st.total_internal;
      const float wr = kr + (refracts ? 0.0f : kt);
      if (wr > 0) {
        ++st.secondary;
        reflected = shade(top, lifted, refl, depth + 1, budget, lights, st);
        out += wr * reflected;
      }
      if (refracts) {
        ++st.secondary;
        out += kt * shade(top, offset_ray_origin(p, -nf), trans, depth + 1, budget, lights, st);
      }
    }
    return out;
  }
};

RayTracer::RayTracer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RayTracer::~RayTracer() = default;

Result<std::unique_ptr<RayTracer>> RayTracer::create(RtScene scene) {
  if (scene.objects.empty()) return fail("the ray-traced scene has no objects");
  if (!scene.background.allFinite()) return fail("background colour is not finite");
  for (size_t i = 0; i < scene.lights.size(); ++i)
    if (!scene.lights[i].position.allFinite() || !scene.lights[i].intensity.allFinite())
      return fail(fmt::format("light {} is not finite", i));
  for (const auto& o : scene.objects) {
    if (auto st = o.mesh.validate("object '" + o.name + "'"); !st) return std::unexpected(st.error());
    if (auto st = check_material("object '" + o.name + "'", o.material, scene, !o.mesh.uvs.empty()); !st)
      return std::unexpected(st.error());
    if (!o.world_from_object.matrix().allFinite()) return fail("object '" + o.name + "': pose is not finite");
  }
  for (const auto& c : scene.curves) {
    if (auto st = c.validate(); !st) return std::unexpected(st.error());
    if (auto st = check_material("curves '" + c.name + "'", c.material, scene, false); !st) return std::unexpected(st.error());
  }
  Stopwatch sw;
  auto impl = std::make_unique<Impl>();
  impl->scene = std::move(scene);
  Impl& I = *impl;
  // One build thread: the scenes are small, and an idle TBB pool would
  // compete with the render threads for the cores.
  I.device = rtcNewDevice("threads=1");
  if (!I.device) return fail(fmt::format("Embree: cannot create a device (error {})", int(rtcGetDeviceError(nullptr))));
  for (const auto& o : I.scene.objects) {
    I.normal_from_object.push_back(o.world_from_object.linear().inverse().transpose().cast<float>());
    const Eigen::Isometry3f pose = o.world_from_object.cast<float>();
    for (const auto& v : o.mesh.vertices) I.bounds.extend(pose * v);
    int same = -1;
    for (size_t u = 0; u < I.meshes.size() && same < 0; ++u)
      if (same_mesh(*I.meshes[u], o.mesh)) same = static_cast<int>(u);
    if (same >= 0) {
      I.mesh_of.push_back(same);
      continue;
    }
    I.mesh_of.push_back(static_cast<int>(I.meshes.size()));
    I.meshes.push_back(&o.mesh);
    std::vector<RTCScene> levels;
    for (const auto& faces : o.mesh.levels) {
      RTCScene s = rtcNewScene(I.device);
      rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_HIGH);
      RTCGeometry g = rtcNewGeometry(I.device, RTC_GEOMETRY_TYPE_TRIANGLE);
      auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                             3 * sizeof(float), o.mesh.vertices.size()));
      std::memcpy(vb, o.mesh.vertices.data(), o.mesh.vertices.size() * 3 * sizeof(float));
      auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                3 * sizeof(unsigned), faces.size()));
      std::memcpy(ib, faces.data(), faces.size() * 3 * sizeof(unsigned));
      rtcCommitGeometry(g);
      rtcAttachGeometry(s, g);
      rtcReleaseGeometry(g);
      rtcCommitScene(s);
      levels.push_back(s);
    }
    I.mesh_levels.push_back(std::move(levels));
  }
  for (const auto& c : I.scene.curves) {
    for (const auto& p : c.points) {
      I.bounds.extend(p.head<3>() - Vector3f::Constant(p.w()));
      I.bounds.extend(p.head<3>() + Vector3f::Constant(p.w()));
    }
    RTCScene s = rtcNewScene(I.device);
    rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(I.device, RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE);
    auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4,
                                                           4 * sizeof(float), c.points.size()));
    std::memcpy(vb, c.points.data(), c.points.size() * 4 * sizeof(float));
    auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT,
                                                              sizeof(unsigned), c.segments.size()));
    std::memcpy(ib, c.segments.data(), c.segments.size() * sizeof(unsigned));
    rtcCommitGeometry(g);
    rtcAttachGeometry(s, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(s);
    I.curve_scenes.push_back(s);
  }
  const Vector3f pad = Vector3f::Constant(1e-4f * I.bounds.sizes().maxCoeff()) +
                       1e-5f * I.bounds.min().cwiseAbs().cwiseMax(I.bounds.max().cwiseAbs());
  I.bounds.min() -= pad;
  I.bounds.max() += pad;
  std::map<std::vector<int>, int> made;
  for (int q = 1; q <= kQuanta; ++q) {
    auto detail = I.detail_for(static_cast<double>(q) / kQuanta);
    auto it = made.find(detail);
    if (it == made.end()) {
      RTCScene top = rtcNewScene(I.device);
      for (size_t j = 0; j < I.scene.objects.size(); ++j) {
        RTCGeometry inst = rtcNewGeometry(I.device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(inst, I.mesh_levels[I.mesh_of[j]][detail[j]]);
        const Eigen::Matrix<float, 3, 4> xfm = I.scene.objects[j].world_from_object.matrix().topRows<3>().cast<float>();
        rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, xfm.data());
        rtcCommitGeometry(inst);
        rtcAttachGeometryByID(top, inst, static_cast<unsigned>(j));
        rtcReleaseGeometry(inst);
      }
      for (size_t c = 0; c < I.curve_scenes.size(); ++c) {
        RTCGeometry inst = rtcNewGeometry(I.device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(inst, I.curve_scenes[c]);
        const Eigen::Matrix<float, 3, 4> xfm = Eigen::Matrix<float, 3, 4>::Identity();
        rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, xfm.data());
        rtcCommitGeometry(inst);
        rtcAttachGeometryByID(top, inst, static_cast<unsigned>(I.scene.objects.size() + c));
        rtcReleaseGeometry(inst);
      }
      rtcCommitScene(top);
      it = made.emplace(detail, static_cast<int>(I.tops.size())).first;
      I.tops.push_back(top);
      I.top_detail.push_back(detail);
    }
    I.quantum_top[q] = it->second;
  }
  I.quantum_top[0] = I.quantum_top[1];
  if (rtcGetDeviceError(I.device) != RTC_ERROR_NONE) return fail("Embree: building the scene failed");
  I.build_seconds = sw.seconds();
  return std::unique_ptr<RayTracer>(new RayTracer(std::move(impl)));
}

Vector3f RayTracer::trace(const Vector3d& origin, const Vector3d& dir, double level, int reflect_max, TraceStats* stats,
                          const std::vector<PointLight>* lights) const {
  TraceStats local;
  return impl_->trace_unit(origin.cast<float>(), dir.normalized().cast<float>(), static_cast<float>(level), reflect_max,
                           lights ? *lights : impl_->scene.lights, stats ? *stats : local);
}

RtHit RayTracer::intersect(const Vector3f& origin, const Vector3f& dir, float t_far) const {
  const Impl& I = *impl_;
  const int top = I.quantum_top[kQuanta];
  RtHit out;
  if (I.misses_bounds(origin, dir)) return out;
  const Hit h = I.intersect(top, origin, dir, t_far);
  if (!h.found) return out;
  out.found = true;
  out.t = h.t;
  out.prim = h.prim;
  const int n_obj = static_cast<int>(I.scene.objects.size());
  if (h.object < n_obj)
    out.object = h.object;
  else
    out.curves = h.object - n_obj;
  out.normal = I.geometric_normal(top, h);
  if (!out.normal.allFinite()) out.normal = -dir.normalized();
  return out;
}

TraceResult RayTracer::render(const Screen& screen, const Vector3d& eye, const TraceOptions& options) const {
  Stopwatch sw;
  TraceResult r;
  r.color = ImageF(screen.width, screen.height, 3);
  r.level = ImageF(screen.width, screen.height, 1);
  const int tile = std::max(1, options.tile);
  const int tx = (screen.width + tile - 1) / tile, ty = (screen.height + tile - 1) / tile;
  std::vector<TraceStats> per_tile(static_cast<size_t>(tx) * ty);
  const Vector3f bg = impl_->scene.background;
  // Rays in single precision, as Embree takes them.
  const Vector3f eye_f = eye.cast<float>(), corner = (screen.corner - eye).cast<float>();
  const Vector3f step_x = (screen.right / screen.width).cast<float>(), step_y = (screen.down / screen.height).cast<float>();
  const Vector3f gf = options.gaze.forward.cast<float>(), gr = options.gaze.right.cast<float>(), gu = options.gaze.up.cast<float>();
  parallel_for(tx * ty, options.threads, [&](int t) {
    TraceStats& st = per_tile[t];
    const int x0 = (t % tx) * tile, y0 = (t / tx) * tile;
    const int x1 = std::min(screen.width, x0 + tile), y1 = std::min(screen.height, y0 + tile);
    // A tile wholly in the central field or wholly behind the field's edge
    // needs no per-pixel level (visual_field.h, field_region).
    const Vector3d corners[4] = {screen.point(x0, y0) - eye, screen.point(x1 - 1, y0) - eye, screen.point(x0, y1 - 1) - eye,
                                 screen.point(x1 - 1, y1 - 1) - eye};
    const FieldRegion region = options.field_lod ? field_region(options.gaze, corners) : FieldRegion::kCentral;
    // A tile whose rays all pass beside the scene's box is background at any
    // level: no ray is traced there, in the full render as in the LOD one.
    const bool empty = impl_->tile_misses_bounds(eye, corners);
    // Directions and (in a mixed tile) levels come kFieldBatch pixels of a
    // row at a time, the levels in SIMD.
    std::array<Vector3f, kFieldBatch> dirs;
    std::array<float, kFieldBatch> df{}, dr{}, du{}, lv{};
    const auto ray_dir = [&](int x, int y) {
      Vector3f v = corner + (x + 0.5f) * step_x + (y + 0.5f) * step_y;
      return Vector3f(v / v.norm());
    };
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        ++st.pixels;
        const int lane = (x - x0) % kFieldBatch;
        if (lane == 0 && region != FieldRegion::kOutside) {  // outside: background, no ray
          const int n = std::min(kFieldBatch, x1 - x);
          for (int i = 0; i < n; ++i) dirs[i] = ray_dir(x + i, y);
          if (region == FieldRegion::kMixed) {
            for (int i = 0; i < kFieldBatch; ++i) {
              const Vector3f& di = dirs[std::min(i, n - 1)];  // past the tile: repeat its last pixel
              df[i] = gf.dot(di), dr[i] = gr.dot(di), du[i] = gu.dot(di);
            }
            field_levels(df.data(), dr.data(), du.data(), lv.data());
          }
        }
        const Vector3f& dir = dirs[lane];
        const float level = region == FieldRegion::kCentral ? 1.0f : region == FieldRegion::kOutside ? 0.0f : lv[lane];
        r.level.at(x, y) = level;
        Vector3f c = bg;
        if (level <= 0) {
          ++st.outside_field;
        } else {
          if (level >= 1) ++st.central;
          if (empty) {
            ++st.empty_tiles_pixels;
            if (impl_->scene.environment) c = impl_->scene.environment->lookup(dir.cast<double>());
          } else
            c = impl_->trace_unit(eye_f, dir, level, options.reflect_max, impl_->scene.lights, st);
        }
        for (int ch = 0; ch < 3; ++ch) r.color.at(x, y, ch) = c[ch];
      }
  });
  for (const auto& s : per_tile) r.stats.add(s);
  r.stats.seconds = sw.seconds();
  return r;
}

std::vector<int> RayTracer::detail_for(double level) const { return impl_->detail_for(level); }
const RtScene& RayTracer::scene() const { return impl_->scene; }
double RayTracer::build_seconds() const { return impl_->build_seconds; }
size_t RayTracer::top_scenes() const { return impl_->tops.size(); }

}  // namespace s2r
