#include "render/model_renderer.h"

#include <epoxy/gl.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

#include "core/image_io.h"
#include "core/mesh.h"
#include "core/parallel.h"
#include "core/paths.h"
#include "core/report.h"
#include "render/gl_program.h"
#include "render/glossy_renderer.h"
#include "reconstruct/splat_composite.h"
#include "reconstruct/splat_fit.h"

namespace s2r {

namespace {

// Shared GLSL: the lens model and the view's projection. The view's vertices
// go through the same Brown-Conrady model as the photos, and the clip
// coordinates stay linear in the camera-frame point where the lens is not
// applied (at or before the near plane), so clipping still works there.
const char* kCommon = R"(
vec2 distort(vec2 x, vec4 d, float k3) {
  float r2 = dot(x, x);
  float radial = 1.0 + r2 * (d.x + r2 * (d.y + r2 * k3));
  return x * radial + vec2(2.0 * d.z * x.x * x.y + d.w * (r2 + 2.0 * x.x * x.x),
                           d.z * (r2 + 2.0 * x.y * x.y) + 2.0 * d.w * x.x * x.y);
}
struct Cam { mat4 cfw; vec4 k; vec4 d; vec4 extra; vec4 centre; };  // extra: k3 width height layer; centre.w: max r^2
layout(std430, binding = 1) readonly buffer Cams { Cam cams[]; };
)";

const char* kViewUniforms = R"(
uniform mat4 u_view_cfw;
uniform vec4 u_view_k;
uniform vec4 u_view_d;
uniform float u_view_k3;
uniform vec2 u_view_size;
uniform vec2 u_near_far;
uniform int u_view_distort;
vec4 to_clip(vec3 world) {
  vec3 p = (u_view_cfw * vec4(world, 1.0)).xyz;
  float n = u_near_far.x, f = u_near_far.y;
  vec2 q = p.xy;
  if (u_view_distort != 0 && p.z > n) q = distort(p.xy / p.z, u_view_d, u_view_k3) * p.z;
  float cx = (2.0 * u_view_k.x * q.x + (2.0 * u_view_k.z + 1.0) * p.z) / u_view_size.x - p.z;
  float cy = p.z - (2.0 * u_view_k.y * q.y + (2.0 * u_view_k.w + 1.0) * p.z) / u_view_size.y;
  return vec4(cx, cy, (f + n) / (f - n) * p.z - 2.0 * f * n / (f - n), p.z);
}
)";

const char* kTexel = R"(
uniform sampler2DArray u_color;
uniform sampler2DArray u_dist;
uniform vec2 u_tex_size;
// Camera ci at world point P: 0 outside its image, 1 the texel agrees with P
// (|d - D| < tol), 2 the camera sees through P (its ray hits nothing, or
// hits beyond P by more than tol: P is empty space), 3 P is hidden from the
// camera (D < d - tol: no information). col, D and d are set from 1 on.
int camera_at(int ci, vec3 P, float tol, out vec3 col, out float D, out float d) {
  col = vec3(0.0);
  D = 0.0;
  d = 0.0;
  if (cams[ci].extra.w < 0.0) return 0;
  vec3 p = (cams[ci].cfw * vec4(P, 1.0)).xyz;
  if (p.z <= 1e-6) return 0;
  vec2 xn = p.xy / p.z;
  if (dot(xn, xn) > cams[ci].centre.w) return 0;  // outside the lens model's field
  vec2 px = cams[ci].k.xy * distort(xn, cams[ci].d, cams[ci].extra.x) + cams[ci].k.zw;
  if (px.x < -0.5 || px.y < -0.5 || px.x >= cams[ci].extra.y - 0.5 || px.y >= cams[ci].extra.z - 0.5) return 0;
  col = texture(u_color, vec3((px + 0.5) / u_tex_size, cams[ci].extra.w)).rgb;
  D = texelFetch(u_dist, ivec3(ivec2(floor(px + 0.5)), int(cams[ci].extra.w)), 0).r;
  d = length(P - cams[ci].centre.xyz);
  if (!(D > 0.0) || D > d + tol) return 2;
  return D < d - tol ? 3 : 1;
}
int texel_state(int ci, vec3 P, float tol, out vec3 col) {
  float D, d;
  return camera_at(ci, P, tol, col, D, d);
}
vec3 palette(int ci) { return 0.5 + 0.5 * cos(6.2831853 * (float(ci) * 0.618034 + vec3(0.0, 0.33, 0.67))); }
)";

const char* kBillboardVertex = R"(
struct Facet { float cx, cy, cz, size, nx, ny, nz, rel; uint first, count; };
layout(std430, binding = 0) readonly buffer Facets { Facet facets[]; };
layout(location = 0) in uint a_facet;
layout(location = 1) in ivec4 a_cams;
layout(location = 2) in vec4 a_weights;
uniform vec3 u_eye;
uniform vec3 u_up;
uniform float u_scale;
out vec3 v_world;
flat out ivec4 v_cams;
flat out vec4 v_weights;
flat out float v_size;
flat out float v_rel;
void main() {
  Facet f = facets[a_facet];
  vec3 c = vec3(f.cx, f.cy, f.cz);
  vec3 v = u_eye - c;
  float len = length(v);
  v = len > 0.0 ? v / len : vec3(0.0, 0.0, 1.0);
  vec3 r = cross(u_up, v);
  if (dot(r, r) < 1e-12) r = cross(abs(v.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0), v);
  r = normalize(r);
  vec3 up = cross(v, r);
  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
  v_world = c + (corner.x * r + corner.y * up) * (0.5 * u_scale * f.size);
  gl_Position = to_clip(v_world);
  v_cams = a_cams;
  v_weights = a_weights;
  v_size = f.size;
  v_rel = f.rel;
}
)";

const char* kBillboardFragment = R"(
in vec3 v_world;
flat in ivec4 v_cams;
flat in vec4 v_weights;
flat in float v_size;
flat in float v_rel;
uniform int u_clip;
uniform float u_clip_scale;
uniform int u_by_camera;
uniform int u_probe;
uniform int u_probe_exact;
uniform int u_refine;
uniform int u_clip_fuzzy;
uniform vec3 u_eye;
uniform vec3 u_view_forward;
uniform float u_view_focal;
uniform float u_px_error;
out vec4 frag;
// The billboard point P stands in for the surface point on the view ray, up
// to tol away. Camera ci's distance says where the surface is along its own
// ray through P; moving P along the view ray by (D - d) / cos(angle) puts it
// there for a locally flat surface. A few steps, kept within tol of the
// billboard, and the texel is taken at the refined point.
vec3 refined(int ci, vec3 P0, float tol, vec3 col0) {
  vec3 view_dir = normalize(P0 - u_eye);
  vec3 P = P0;
  vec3 col = col0;
  for (int it = 0; it < u_refine; ++it) {
    vec3 c;
    float D, d;
    if (camera_at(ci, P, tol, c, D, d) != 1) break;
    col = c;
    vec3 next = P + (D - d) / max(dot(normalize(P - cams[ci].centre.xyz), view_dir), 0.5) * view_dir;
    if (length(next - P0) > tol) break;
    P = next;
  }
  vec3 c;
  if (P != P0 && texel_state(ci, P, tol, c) == 1) col = c;
  return col;
}
// A texel drawn |d - D| off its surface point lands (|d - D| sin theta) away
// on screen, theta the angle at P between the view ray and camera ci's ray.
// So the clip may widen where theta is small: up to the depth that keeps the
// misplacement under u_px_error pixels. At theta = 0 (the view is the
// camera's) any depth is exact, as in the photo.
float camera_tol(int ci, float tol) {
  vec3 view_dir = normalize(v_world - u_eye);
  vec3 cam_dir = normalize(v_world - cams[ci].centre.xyz);
  float s = length(cross(view_dir, cam_dir));
  float pixel_m = u_px_error * dot(v_world - u_eye, u_view_forward) / u_view_focal;
  return max(tol, pixel_m / max(s, 1e-6));
}
void main() {
  vec3 acc = vec3(0.0);
  float wsum = 0.0;
  float tol = u_clip_scale * v_size;
  vec3 col;
  // Silhouette-only (fuzzy) evidence has no measured depth: its cameras'
  // distances are the hull's, so clipping against them is arbitrary there.
  // Those facets are drawn image-based, without the clip.
  bool clip = u_clip != 0 && (u_clip_fuzzy != 0 || v_rel > 0.0);
  // The input camera nearest the view carves too: where it sees through
  // the fragment, the fragment is empty space.
  if (u_probe >= 0 && (clip || u_probe_exact != 0)) {
    int probe = texel_state(u_probe, v_world, camera_tol(u_probe, tol), col);
    if (clip && probe == 2) discard;
    // The view is the probe camera's own (the same centre): every point on
    // a pixel's ray shows that camera's texel, whichever facet draws it and
    // whatever the facet's own cameras say (the photo is exact); facets
    // drawn without the clip (fuzzy evidence) too.
    if (u_probe_exact != 0 && probe != 0) {
      frag = vec4(u_by_camera != 0 ? palette(u_probe) : col, 1.0);
      return;
    }
  }
  for (int j = 0; j < 4; ++j) {
    int ci = v_cams[j];
    if (ci < 0) break;
    int state = texel_state(ci, v_world, camera_tol(ci, tol), col);
    if (state == 0) continue;
    if (clip) {
      if (state == 2) discard;
      if (state == 3) continue;
      if (u_refine > 0) col = refined(ci, v_world, camera_tol(ci, tol), col);
    }
    if (u_by_camera != 0) col = palette(ci);
    acc += v_weights[j] * col;
    wsum += v_weights[j];
  }
  if (!(wsum > 0.0)) discard;
  frag = vec4(acc / wsum, 1.0);
}
)";

const char* kMeshVertex = R"(
layout(location = 0) in vec3 a_pos;
out vec3 v_world;
void main() {
  v_world = a_pos;
  gl_Position = to_clip(a_pos);
}
)";

// Per fragment: the k best visible cameras by angle, the same weights as the
// billboards' (render/facet_selection.h), the (k+1)-th as the threshold.
const char* kMeshFragment = R"(
in vec3 v_world;
uniform int u_camera_count;
uniform int u_use_list;       // 1: only the cameras in u_cam_list (the view's nearest by direction)
uniform int u_cam_list[16];
uniform int u_k;
uniform vec3 u_eye;
uniform float u_tol;
uniform int u_by_camera;
uniform int u_flat;
out vec4 frag;
void main() {
  if (u_flat != 0) { frag = vec4(0.9, 0.9, 0.9, 1.0); return; }
  vec3 to_eye = normalize(u_eye - v_world);
  float best_a[5];
  vec3 best_c[5];
  int n = 0;
  float fallback_a = 10.0;  // no camera sees the fragment: the nearest by angle that contains it
  vec3 fallback = vec3(0.0);
  for (int li = 0; li < u_camera_count; ++li) {
    int ci = u_use_list != 0 ? u_cam_list[li] : li;
    vec3 to_cam = normalize(cams[ci].centre.xyz - v_world);
    float a = atan(length(cross(to_cam, to_eye)), dot(to_cam, to_eye));
    if (n > u_k && a >= best_a[u_k] && a >= fallback_a) continue;
    vec3 col;
    int state = texel_state(ci, v_world, u_tol, col);
    if (state == 0) continue;
    if (a < fallback_a) { fallback_a = a; fallback = u_by_camera != 0 ? palette(ci) : col; }
    if (state != 1) continue;
    if (u_by_camera != 0) col = palette(ci);
    int j = min(n, u_k);
    while (j > 0 && best_a[j - 1] > a) { best_a[j] = best_a[j - 1]; best_c[j] = best_c[j - 1]; --j; }
    best_a[j] = a;
    best_c[j] = col;
    n = min(n + 1, u_k + 1);
  }
  if (n == 0) {
    if (fallback_a > 9.0) discard;
    frag = vec4(fallback, 1.0);
    return;
  }
  if (best_a[0] < 1e-6) { frag = vec4(best_c[0], 1.0); return; }
  int used = min(n, u_k);
  float threshold = n > u_k ? best_a[u_k] : 3.14159265;
  vec3 acc = vec3(0.0);
  float wsum = 0.0;
  for (int j = 0; j < used; ++j) {
    float w = max(0.0, 1.0 - best_a[j] / threshold) / best_a[j];
    acc += w * best_c[j];
    wsum += w;
  }
  frag = vec4(wsum > 0.0 ? acc / wsum : best_c[0], 1.0);
}
)";

// Fitted billboards (reconstruct/splat_fit.h): the image formation the fit
// used, drawn back to front into a half-float target. Each facet is a
// screen-aligned square of 3 sigma around its centre's projection (through
// the lens model, as to_clip), its alpha min(0.99, o g) with g the Gaussian
// of the pixel's distance, premultiplied and blended "over".
const char* kSplatVertex = R"(
layout(std430, binding = 2) readonly buffer Splats { float sp[]; };
layout(location = 0) in uint a_splat;
uniform int u_stride;
uniform int u_coeffs;
uniform vec3 u_eye;
uniform float u_pixel_filter;  // px^2: the footprint convolved with it, its energy kept (splat_fit.h)
flat out vec2 v_centre;
flat out float v_sigma;
flat out float v_opacity;
flat out vec3 v_color;
void main() {
  int b = int(a_splat) * u_stride;
  vec3 c = vec3(sp[b], sp[b + 1], sp[b + 2]);
  vec3 p = (u_view_cfw * vec4(c, 1.0)).xyz;
  float s_px = sp[b + 3] * u_view_k.x / max(p.z, 1e-6);
  float v2 = s_px * s_px + u_pixel_filter;
  v_sigma = max(sqrt(v2), 1e-4);
  v_opacity = v2 > 0.0 ? sp[b + 4] * s_px * s_px / v2 : sp[b + 4];
  if (p.z <= u_near_far.x) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); return; }
  vec4 clip = to_clip(c);
  vec2 ndc = clip.xy / clip.w;
  v_centre = vec2(((ndc.x + 1.0) * u_view_size.x - 1.0) * 0.5, ((1.0 - ndc.y) * u_view_size.y - 1.0) * 0.5);
  // Beyond this radius alpha < 1/255 or the footprint is cut: nothing drawn.
  float r = v_sigma * sqrt(min(9.0, 2.0 * log(max(255.0 * v_opacity, 1.0))));
  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
  gl_Position = vec4(ndc + corner * (2.0 * r) / u_view_size, 0.0, 1.0);
  vec3 d = normalize(c - u_eye);
  float basis[9];
  basis[0] = 0.28209479177387814;
  basis[1] = -0.4886025119029199 * d.y;
  basis[2] = 0.4886025119029199 * d.z;
  basis[3] = -0.4886025119029199 * d.x;
  basis[4] = 1.0925484305920792 * d.x * d.y;
  basis[5] = -1.0925484305920792 * d.y * d.z;
  basis[6] = 0.31539156525252005 * (2.0 * d.z * d.z - d.x * d.x - d.y * d.y);
  basis[7] = -1.0925484305920792 * d.x * d.z;
  basis[8] = 0.5462742152960396 * (d.x * d.x - d.y * d.y);
  vec3 col = vec3(0.5);
  for (int k = 0; k < u_coeffs; ++k) col += basis[k] * vec3(sp[b + 5 + 3 * k], sp[b + 6 + 3 * k], sp[b + 7 + 3 * k]);
  v_color = max(col, vec3(0.0));
}
)";

const char* kSplatFragment = R"(
flat in vec2 v_centre;
flat in float v_sigma;
flat in float v_opacity;
flat in vec3 v_color;
uniform vec2 u_size;
out vec4 frag;
void main() {
  vec2 d = vec2(gl_FragCoord.x - 0.5, u_size.y - gl_FragCoord.y - 0.5) - v_centre;
  float d2 = dot(d, d);
  if (d2 > 9.0 * v_sigma * v_sigma) discard;
  float a = min(0.99, v_opacity * exp(-0.5 * d2 / (v_sigma * v_sigma)));
  if (a < 1.0 / 255.0) discard;
  frag = vec4(v_color * a, a);
}
)";

// The CPU pass's image (premultiplied colour and transmittance, rows top to
// bottom) laid over the target: one triangle over the whole viewport.
const char* kCompositedVertex = R"(
void main() {
  gl_Position = vec4(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0, 0.0, 1.0);
}
)";

const char* kCompositedFragment = R"(
uniform sampler2D u_image;
out vec4 frag;
void main() {
  ivec2 size = textureSize(u_image, 0);
  vec4 c = texelFetch(u_image, ivec2(gl_FragCoord.x, size.y - 1 - int(gl_FragCoord.y)), 0);
  frag = vec4(c.rgb, 1.0 - c.a);
}
)";

std::string shader(std::initializer_list<const char*> parts) {
  std::string s = "#version 430 core\n";
  for (const char* p : parts) s += p;
  return s;
}

void set_view_uniforms(const GlProgram& p, const ViewCamera& view, float near_m, float far_m) {
  const Eigen::Matrix4f cfw = view.world_from_camera.inverse().matrix().cast<float>();
  const Intrinsics& K = view.K;
  glUniformMatrix4fv(p.uniform("u_view_cfw"), 1, GL_FALSE, cfw.data());
  glUniform4f(p.uniform("u_view_k"), float(K.fx), float(K.fy), float(K.cx), float(K.cy));
  glUniform4f(p.uniform("u_view_d"), float(K.dist[0]), float(K.dist[1]), float(K.dist[2]), float(K.dist[3]));
  glUniform1f(p.uniform("u_view_k3"), float(K.dist[4]));
  glUniform2f(p.uniform("u_view_size"), float(K.width), float(K.height));
  glUniform2f(p.uniform("u_near_far"), near_m, far_m);
  glUniform1i(p.uniform("u_view_distort"), K.has_distortion() ? 1 : 0);
  const Eigen::Vector3d eye = view.eye();
  glUniform3f(p.uniform("u_eye"), float(eye.x()), float(eye.y()), float(eye.z()));
}

// The largest |x/z|^2 the lens model is trusted at: the image corners'
// undistorted directions, with 20 % to spare.
double max_field_r2(const Intrinsics& K) {
  double r2 = 0;
  for (double x : {-0.5, K.width - 0.5})
    for (double y : {-0.5, K.height - 0.5}) {
      const Eigen::Vector2d xd((x - K.cx) / K.fx, (y - K.cy) / K.fy);
      const auto xn = K.undistort(xd);
      r2 = std::max(r2, (xn ? *xn : xd).squaredNorm());
    }
  return 1.44 * r2;
}

double bounds_radius(const Model& m) { return m.bounds.isEmpty() ? 1.0 : 0.5 * m.bounds.diagonal().norm(); }

// The textured input camera most like the view: near it, looking the same
// way (the bounds' radius weighs direction against distance). -1: none.
int nearest_camera(const Model& m, const ViewCamera& view) {
  const double radius = bounds_radius(m);
  const Eigen::Vector3d z = view.world_from_camera.linear().col(2);
  int best = -1;
  double best_score = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < m.cameras.size(); ++i) {
    const auto& c = m.cameras[i];
    if (c.texture.empty()) continue;
    const double score = (c.world_from_camera.translation() - view.eye()).norm() +
                         radius * (1 - z.dot(c.world_from_camera.linear().col(2)));
    if (score < best_score) best_score = score, best = int(i);
  }
  return best;
}

// The textured input camera the view is (its centre, axes and intrinsics,
// to a millionth): a training view redrawn. -1: none.
int same_camera(const Model& m, const ViewCamera& view) {
  const int c = nearest_camera(m, view);
  if (c < 0) return -1;
  const ModelCamera& mc = m.cameras[size_t(c)];
  const Intrinsics &a = mc.intrinsics, &b = view.K;
  const double tol = 1e-6;
  const bool same = (mc.world_from_camera.translation() - view.eye()).norm() <= tol * bounds_radius(m) &&
                    (mc.world_from_camera.linear() - view.world_from_camera.linear()).cwiseAbs().maxCoeff() <= tol &&
                    a.width == b.width && a.height == b.height && std::abs(a.fx - b.fx) <= tol * a.fx &&
                    std::abs(a.fy - b.fy) <= tol * a.fy && std::abs(a.cx - b.cx) <= tol * a.fx && std::abs(a.cy - b.cy) <= tol * a.fy;
  return same ? c : -1;
}

// Silhouette pixels of a photo are often hit by the object but missed by the
// fused surface through their centre (the surface sits a fraction of a
// voxel inside, and the edge pixel is part object): such a texel would never
// pass depth clipping and would carve the fragment as empty space. One pixel
// around every hit takes the nearest hit's distance instead.
void extend_silhouette_distance(ImageF& d) {
  const ImageF in = d;
  for (int y = 0; y < d.height; ++y)
    for (int x = 0; x < d.width; ++x) {
      if (in.at(x, y) > 0) continue;
      float best = 0;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int u = x + dx, v = y + dy;
          if (u < 0 || v < 0 || u >= d.width || v >= d.height) continue;
          const float z = in.at(u, v);
          if (z > 0 && (best == 0 || z < best)) best = z;
        }
      d.at(x, y) = best;
    }
}

// Each facet's luminance (Rec. 709 weights on the stored 8-bit values, 0..1)
// at its centre in its most head-on camera (the first that sees it when it
// has no normal); NaN where that texel is background. The octree LOD's
// luminance test reads the range of these over a node.
std::vector<float> facet_luminance(const Model& model, const std::vector<RgbazImage>& tex) {
  std::vector<float> lum(model.facets.size(), std::numeric_limits<float>::quiet_NaN());
  std::vector<Eigen::Isometry3d> cfw;
  for (const auto& c : model.cameras) cfw.push_back(c.world_from_camera.inverse());
  for (size_t i = 0; i < model.facets.size(); ++i) {
    const FacetRecord& f = model.facets[i];
    const Eigen::Vector3d c(f.center[0], f.center[1], f.center[2]), n(f.normal[0], f.normal[1], f.normal[2]);
    int best = -1;
    double best_dot = -2;
    for (uint32_t j = 0; j < f.camera_count; ++j) {
      const uint32_t ci = model.facet_cameras[f.first_camera + j];
      if (tex[ci].rgba.empty()) continue;
      const double d = n.dot((model.cameras[ci].world_from_camera.translation() - c).normalized());
      if (d > best_dot) best_dot = d, best = int(ci);
    }
    if (best < 0) continue;
    const auto px = model.cameras[size_t(best)].intrinsics.project(cfw[size_t(best)] * c);
    const ImageU8& img = tex[size_t(best)].rgba;
    if (!px) continue;
    const int x = int(std::lround(px->x())), y = int(std::lround(px->y()));
    if (x < 0 || y < 0 || x >= img.width || y >= img.height) continue;
    const uint8_t* p = &img.data[(size_t(y) * img.width + x) * 4];
    if (p[3] == 0) continue;
    lum[i] = float((0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) / 255.0);
  }
  return lum;
}

// Per patch-mesh triangle: how reliable the geometry around it is, the most
// reliable facet within a base voxel of any of its corners (dilated, so the
// mesh drawn for reliable geometry meets the billboards drawn for the rest
// with an overlap, not a gap). Facets are hashed by cells of two voxels.
std::vector<float> triangle_reliability(const Mesh& mesh, const Model& model) {
  const double c = model.voxel_size_m > 0 ? model.voxel_size_m : 1.0;
  // Cells of 2 voxels: every facet within a voxel of a point is in the point's 27.
  auto key = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3i k = (p / (2 * c)).array().floor().cast<int>();
    return (uint64_t(uint32_t(k.x()) & 0x1FFFFF) << 42) | (uint64_t(uint32_t(k.y()) & 0x1FFFFF) << 21) |
           uint64_t(uint32_t(k.z()) & 0x1FFFFF);
  };
  std::unordered_map<uint64_t, std::vector<uint32_t>> cells;
  for (uint32_t i = 0; i < model.facets.size(); ++i) {
    const float* f = model.facets[i].center;
    cells[key(Eigen::Vector3d(f[0], f[1], f[2]))].push_back(i);
  }
  std::vector<float> at_vertex(mesh.vertices.size(), 0.f);
  parallel_for(int(mesh.vertices.size()), 0, [&](int v) {
    const Eigen::Vector3d p = mesh.vertices[size_t(v)].cast<double>();
    float best = 0;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const auto it = cells.find(key(p + 2 * c * Eigen::Vector3d(dx, dy, dz)));
          if (it == cells.end()) continue;
          for (uint32_t i : it->second) {
            const FacetRecord& f = model.facets[i];
            if ((Eigen::Vector3d(f.center[0], f.center[1], f.center[2]) - p).norm() <= 1.01 * c)  // float centres
              best = std::max(best, f.reliability);
          }
        }
    at_vertex[size_t(v)] = best;
  });
  std::vector<float> out(mesh.faces.size());
  for (size_t t = 0; t < mesh.faces.size(); ++t) {
    const auto& f = mesh.faces[t];
    out[t] = std::max({at_vertex[size_t(f[0])], at_vertex[size_t(f[1])], at_vertex[size_t(f[2])]});
  }
  return out;
}

}  // namespace

double camera_field_r2(const Intrinsics& K) { return max_field_r2(K); }
void fill_silhouette_distance(ImageF& distance) { extend_silhouette_distance(distance); }

struct ModelRenderer::Programs {
  GlProgram billboard, mesh, splat, composited;
};

Result<std::unique_ptr<ModelRenderer>> ModelRenderer::create(Model model_in, const std::filesystem::path& dir,
                                                             int threads) {
  if (epoxy_gl_version() < 43)
    return fail("the model renderer needs OpenGL 4.3 (shader storage buffers); this context has " +
                std::to_string(epoxy_gl_version() / 10) + "." + std::to_string(epoxy_gl_version() % 10));
  std::unique_ptr<ModelRenderer> r(new ModelRenderer());
  r->model_ = std::move(model_in);
  const Model& model = r->model_;
  r->has_reliable_ = std::any_of(model.facets.begin(), model.facets.end(), [](const FacetRecord& f) { return f.reliability > 0; });
  auto bb = GlProgram::build(shader({kCommon, kViewUniforms, kBillboardVertex}), shader({kCommon, kTexel, kBillboardFragment}));
  if (!bb) return std::unexpected(bb.error());
  auto me = GlProgram::build(shader({kCommon, kViewUniforms, kMeshVertex}), shader({kCommon, kTexel, kMeshFragment}));
  if (!me) return std::unexpected(me.error());
  auto sp = GlProgram::build(shader({kCommon, kViewUniforms, kSplatVertex}), shader({kSplatFragment}));
  if (!sp) return std::unexpected(sp.error());
  auto co = GlProgram::build(shader({kCompositedVertex}), shader({kCompositedFragment}));
  if (!co) return std::unexpected(co.error());
  r->programs_.reset(new Programs{std::move(*bb), std::move(*me), std::move(*sp), std::move(*co)});
  r->threads_ = threads;
  const std::string gl_renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  for (const char* sw : {"llvmpipe", "softpipe", "SwiftShader", "swrast"})
    if (gl_renderer.find(sw) != std::string::npos) r->software_gl_ = true;
  glGenVertexArrays(1, &r->screen_vao_);  // full-viewport triangles: no attributes (gl_VertexID)
  if (!model.splats.empty()) {
    order_splats_spatially(r->model_.splats, r->model_.splat_layout.stride());
    r->compositor_ = std::make_unique<SplatCompositor>();
  }

  r->dir_ = dir;
  r->has_textures_ = std::any_of(model.cameras.begin(), model.cameras.end(), [](const ModelCamera& c) { return !c.texture.empty(); });
  // What draws from the photos (camera textures, the facets' hierarchy, the
  // meshes) is loaded when first drawn: a fitted model's view never needs it.
  if (model.splats.empty())
    if (auto st = r->load_photo_passes(); !st) return std::unexpected(st.error());
  if (glGetError() != GL_NO_ERROR) return fail("OpenGL error while uploading the model");
  return r;
}

// The camera textures, the facets' hierarchy and buffers, and the meshes:
// everything billboards and meshes draw with. Once; an error is kept and
// returned again.
Status ModelRenderer::load_photo_passes() {
  if (photo_passes_) return *photo_passes_;
  photo_passes_ = load_photo_passes_once();
  return *photo_passes_;
}

Status ModelRenderer::load_photo_passes_once() {
  // Camera textures, read in parallel, into two texture arrays sized to the
  // largest camera (each layer holds its image in the top-left corner).
  const size_t n = model_.cameras.size();
  std::vector<RgbazImage> tex(n);
  std::vector<std::string> errors(n);
  parallel_for(int(n), threads_, [&](int i) {
    const auto& c = model_.cameras[size_t(i)];
    if (c.texture.empty()) return;
    auto t = read_rgbaz(dir_ / c.texture);
    if (!t) errors[size_t(i)] = t.error().message;
    else {
      tex[size_t(i)] = std::move(*t);
      extend_silhouette_distance(tex[size_t(i)].distance);
    }
  });
  for (const auto& e : errors)
    if (!e.empty()) return fail(e);
  int layers = 0;
  std::vector<int> layer(n, -1);
  for (size_t i = 0; i < n; ++i) {
    if (tex[i].rgba.empty()) continue;
    layer[i] = layers++;
    texture_width_ = std::max(texture_width_, tex[i].rgba.width);
    texture_height_ = std::max(texture_height_, tex[i].rgba.height);
  }
  if (layers == 0 && model_.splats.empty())
    return fail("the model has no camera textures (reconstructed without textures?): nothing to texture facets with");
  if (layers > 0) {
    GLint max_layers = 0;
    glGetIntegerv(GL_MAX_ARRAY_TEXTURE_LAYERS, &max_layers);
    if (layers > max_layers) return fail(fmt::format("{} camera textures, the OpenGL driver allows {} layers", layers, max_layers));
    const int W = texture_width_, H = texture_height_;
    glGenTextures(1, &color_array_);
    glBindTexture(GL_TEXTURE_2D_ARRAY, color_array_);
    glTexStorage3D(GL_TEXTURE_2D_ARRAY, 1, GL_RGBA8, W, H, layers);
    glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glGenTextures(1, &distance_array_);
    glBindTexture(GL_TEXTURE_2D_ARRAY, distance_array_);
    glTexStorage3D(GL_TEXTURE_2D_ARRAY, 1, GL_R32F, W, H, layers);
    glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    for (size_t i = 0; i < n; ++i) {
      if (layer[i] < 0) continue;
      const auto& t = tex[i];
      if (t.rgba.channels != 4 || !(t.distance.width == t.rgba.width && t.distance.height == t.rgba.height))
        return fail(model_.cameras[i].texture + ": colour and distance channels differ in size");
      glBindTexture(GL_TEXTURE_2D_ARRAY, color_array_);
      glTexSubImage3D(GL_TEXTURE_2D_ARRAY, 0, 0, 0, layer[i], t.rgba.width, t.rgba.height, 1, GL_RGBA, GL_UNSIGNED_BYTE,
                      t.rgba.data.data());
      glBindTexture(GL_TEXTURE_2D_ARRAY, distance_array_);
      glTexSubImage3D(GL_TEXTURE_2D_ARRAY, 0, 0, 0, layer[i], t.rgba.width, t.rgba.height, 1, GL_RED, GL_FLOAT,
                      t.distance.data.data());
    }
  }
  camera_layer_ = layer;
  texture_bytes_ = size_t(texture_width_) * texture_height_ * layers * 8;
  // A model opened without its octree (ModelLoad) reads it now: only the
  // billboards' level of detail walks it.
  if (!dir_.empty())
    if (auto st = load_octree(dir_, model_); !st) return st;
  hierarchy_ = FacetHierarchy::build(model_, facet_luminance(model_, tex));

  // Cameras: 32 floats each (the GLSL Cam struct, std430).
  std::vector<float> cams(n * 32, 0.f);
  for (size_t i = 0; i < n; ++i) {
    const auto& c = model_.cameras[i];
    float* d = &cams[i * 32];
    const Eigen::Matrix4f cfw = c.world_from_camera.inverse().matrix().cast<float>();
    std::memcpy(d, cfw.data(), 16 * sizeof(float));
    const Intrinsics& K = c.intrinsics;
    const float v[16] = {float(K.fx), float(K.fy), float(K.cx), float(K.cy),
                         float(K.dist[0]), float(K.dist[1]), float(K.dist[2]), float(K.dist[3]),
                         float(K.dist[4]), float(K.width), float(K.height), float(layer[i]),
                         float(c.world_from_camera.translation().x()), float(c.world_from_camera.translation().y()),
                         float(c.world_from_camera.translation().z()), float(max_field_r2(K))};
    std::memcpy(d + 16, v, sizeof(v));
  }
  glGenBuffers(1, &camera_ssbo_);
  glBindBuffer(GL_SHADER_STORAGE_BUFFER, camera_ssbo_);
  glBufferData(GL_SHADER_STORAGE_BUFFER, GLsizeiptr(std::max<size_t>(cams.size(), 32) * sizeof(float)), cams.data(),
               GL_STATIC_DRAW);

  glGenBuffers(1, &facet_ssbo_);
  glBindBuffer(GL_SHADER_STORAGE_BUFFER, facet_ssbo_);
  // The model's facets, then the octree nodes' billboards.
  const auto& facets = hierarchy_.facets();
  glBufferData(GL_SHADER_STORAGE_BUFFER, GLsizeiptr(std::max<size_t>(facets.size(), 1) * sizeof(FacetRecord)),
               facets.empty() ? nullptr : facets.data(), GL_STATIC_DRAW);

  glGenVertexArrays(1, &billboard_vao_);
  glBindVertexArray(billboard_vao_);
  glGenBuffers(1, &instance_vbo_);
  glBindBuffer(GL_ARRAY_BUFFER, instance_vbo_);
  glEnableVertexAttribArray(0);
  glVertexAttribIPointer(0, 1, GL_UNSIGNED_INT, sizeof(FacetInstance), reinterpret_cast<void*>(offsetof(FacetInstance, facet)));
  glVertexAttribDivisor(0, 1);
  glEnableVertexAttribArray(1);
  glVertexAttribIPointer(1, 4, GL_INT, sizeof(FacetInstance), reinterpret_cast<void*>(offsetof(FacetInstance, camera)));
  glVertexAttribDivisor(1, 1);
  glEnableVertexAttribArray(2);
  glVertexAttribPointer(2, 4, GL_FLOAT, GL_FALSE, sizeof(FacetInstance), reinterpret_cast<void*>(offsetof(FacetInstance, weight)));
  glVertexAttribDivisor(2, 1);
  glBindVertexArray(0);

  const std::optional<std::string>* mesh_paths[2] = {&model_.patch_mesh, &model_.surface_mesh};
  for (int k = 0; k < 2; ++k) {
    if (!*mesh_paths[k]) continue;
    auto path = resolve_inside(dir_, **mesh_paths[k]);
    auto mesh = path ? read_ply_mesh(*path) : Result<Mesh>(std::unexpected(path.error()));
    if (!mesh) {
      spdlog::warn("{} not loaded, that mesh pass is off: {}", **mesh_paths[k], mesh.error().message);
      continue;
    }
    if (mesh->faces.empty()) continue;
    if (k == 0) {
      // Most reliable first: the triangles at or above a threshold are a prefix.
      const auto rel = triangle_reliability(*mesh, model_);
      std::vector<uint32_t> order(rel.size());
      for (uint32_t t = 0; t < order.size(); ++t) order[t] = t;
      std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return rel[a] > rel[b]; });
      std::vector<Eigen::Vector3i> faces(order.size());
      triangle_reliability_.resize(order.size());
      for (size_t t = 0; t < order.size(); ++t) {
        faces[t] = mesh->faces[order[t]];
        triangle_reliability_[t] = rel[order[t]];
      }
      mesh->faces = std::move(faces);
    }
    GpuMesh& g = meshes_[k];
    glGenVertexArrays(1, &g.vao);
    glBindVertexArray(g.vao);
    glGenBuffers(1, &g.vbo);
    glBindBuffer(GL_ARRAY_BUFFER, g.vbo);
    glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(mesh->vertices.size() * sizeof(Eigen::Vector3f)), mesh->vertices.data(),
                 GL_STATIC_DRAW);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(Eigen::Vector3f), nullptr);
    glGenBuffers(1, &g.ibo);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.ibo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, GLsizeiptr(mesh->faces.size() * sizeof(Eigen::Vector3i)), mesh->faces.data(),
                 GL_STATIC_DRAW);
    glBindVertexArray(0);
    g.triangles = mesh->faces.size();
  }
  if (glGetError() != GL_NO_ERROR) return fail("OpenGL error while uploading the model's camera textures and meshes");
  return {};
}

ModelRenderer::~ModelRenderer() {
  const unsigned buffers[] = {facet_ssbo_, camera_ssbo_, instance_vbo_, splat_ssbo_, splat_order_vbo_,
                              meshes_[0].vbo, meshes_[0].ibo, meshes_[1].vbo, meshes_[1].ibo};
  for (unsigned b : buffers)
    if (b) glDeleteBuffers(1, &b);
  if (billboard_vao_) glDeleteVertexArrays(1, &billboard_vao_);
  if (splat_vao_) glDeleteVertexArrays(1, &splat_vao_);
  if (screen_vao_) glDeleteVertexArrays(1, &screen_vao_);
  for (const auto& m : meshes_)
    if (m.vao) glDeleteVertexArrays(1, &m.vao);
  if (color_array_) glDeleteTextures(1, &color_array_);
  if (distance_array_) glDeleteTextures(1, &distance_array_);
  if (composited_texture_) glDeleteTextures(1, &composited_texture_);
  if (backdrop_texture_) glDeleteTextures(1, &backdrop_texture_);
}

// One draw's view, options and depth range, shared by its passes.
struct ModelRenderer::Pass {
  const ViewCamera& view;
  const DrawOptions& o;
  float near_m = 0, far_m = 0;
};

namespace {

// Near and far planes from the model's bounds (and the environment's) as
// seen from the eye.
std::pair<float, float> depth_range(const Model& model, const ViewCamera& view, const DrawOptions& o) {
  const Eigen::Vector3d eye = view.eye();
  double far_m = 0;
  for (int c = 0; c < 8; ++c) far_m = std::max(far_m, (model.bounds.corner(Eigen::AlignedBox3d::CornerType(c)) - eye).norm());
  Eigen::AlignedBox3d drawn = model.bounds;
  if (o.environment && !o.environment->bounds().isEmpty()) {
    drawn.extend(o.environment->bounds());
    for (int c = 0; c < 8; ++c) far_m = std::max(far_m, (drawn.corner(Eigen::AlignedBox3d::CornerType(c)) - eye).norm());
  }
  far_m = std::min(std::max(far_m * 1.05, 1e-3), o.far_m);
  const double outside = drawn.exteriorDistance(eye);
  const float near_m = float(std::clamp(0.5 * outside, std::max(far_m * 1e-5, 1e-5), std::max(o.near_m, far_m * 1e-5)));
  return {near_m, float(far_m)};
}

}  // namespace

Result<DrawStats> ModelRenderer::draw(const ViewCamera& view, const DrawOptions& o, const Framebuffer& target) {
  if (view.K.width != target.width() || view.K.height != target.height())
    return fail(fmt::format("view is {}x{} but the target is {}x{}", view.K.width, view.K.height, target.width(), target.height()));
  if (!view.world_from_camera.matrix().allFinite()) return fail("view pose is not finite");
  if (o.geometry == DrawOptions::Geometry::kSplats && model_.splats.empty())
    return fail("the model has no fitted billboards (reconstruct with --fit)");
  const bool mesh_pass = o.geometry == DrawOptions::Geometry::kMesh || o.geometry == DrawOptions::Geometry::kSurface;
  if (o.geometry != DrawOptions::Geometry::kSplats)
    if (auto lp = load_photo_passes(); !lp) return std::unexpected(lp.error());
  if (o.geometry != DrawOptions::Geometry::kSplats && color_array_ == 0)
    return fail("the model has no camera textures: only its fitted billboards can be drawn (--geometry fitted)");
  if (mesh_pass && !has_mesh(o.geometry))
    return fail(o.geometry == DrawOptions::Geometry::kMesh ? "the model has no patch mesh to draw" : "the model has no fused surface mesh to draw");
  Stopwatch clock;
  DrawStats st;
  Pass pass{view, o};
  std::tie(pass.near_m, pass.far_m) = depth_range(model_, view, o);
  if (auto c = clear_and_environment(pass, target, st); !c) return std::unexpected(c.error());
  bind_model_state();
  if (o.geometry == DrawOptions::Geometry::kSplats) {
    if (auto sp = draw_splats(pass, target, st); !sp) return std::unexpected(sp.error());
  } else if (o.geometry == DrawOptions::Geometry::kBillboards) {
    draw_billboards(pass, st);
  } else {
    const GpuMesh& g = meshes_[o.geometry == DrawOptions::Geometry::kSurface ? 1 : 0];
    draw_mesh(pass, g, g.triangles, false, st);
  }
  if (o.backdrop) {
    // Drawn from the photos, at an input camera itself: behind the object,
    // that camera's own photo (what it saw behind the object in that frame;
    // the plate is what the capture's camera sees behind it over all of them).
    const ImageU8* behind = o.backdrop;
    if (o.geometry != DrawOptions::Geometry::kSplats)
      if (const int c = same_camera(model_, view); c >= 0 && camera_layer_[size_t(c)] >= 0 && read_layer(camera_layer_[size_t(c)], view.K.width, view.K.height, own_photo_)) {
        behind = &own_photo_;
        st.backdrop_own_photo = true;
      }
    if (auto b = draw_backdrop(*behind, target); !b) return std::unexpected(b.error());
    st.backdrop_drawn = true;
  }
  glBindVertexArray(0);
  st.cpu_ms = clock.seconds() * 1e3;
  glFinish();
  st.frame_ms = clock.seconds() * 1e3;
  if (const GLenum e = glGetError(); e != GL_NO_ERROR) return fail(fmt::format("OpenGL error 0x{:x} while drawing", e));
  return st;
}

// The target cleared to the background (alpha 0), then the environment
// (backdrop, glossy floor and props) into the same depth buffer.
Status ModelRenderer::clear_and_environment(const Pass& pass, const Framebuffer& target, DrawStats& st) {
  target.bind();
  // With a backdrop plate: cleared to nothing, the plate laid under the model
  // at the end (draw_backdrop).
  if (pass.o.backdrop) glClearColor(0.f, 0.f, 0.f, 0.f);
  else glClearColor(pass.o.background[0], pass.o.background[1], pass.o.background[2], 0.f);
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  if (!pass.o.environment) return {};
  auto env = pass.o.environment->draw_into_bound(pass.view.eye(), screen_for_view(pass.view.K, pass.view.world_from_camera),
                                                 pass.near_m, pass.far_m);
  if (!env) return std::unexpected(with_context(env.error(), "environment"));
  st.environment_drawn = true;
  st.envmap_bound = env->envmap_bound;
  return {};
}

// Depth test on, no blending; the camera textures and the facet and camera
// buffers bound where both programs read them.
void ModelRenderer::bind_model_state() const {
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDisable(GL_CULL_FACE);
  glDisable(GL_BLEND);
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D_ARRAY, color_array_);
  glActiveTexture(GL_TEXTURE1);
  glBindTexture(GL_TEXTURE_2D_ARRAY, distance_array_);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, facet_ssbo_);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, camera_ssbo_);
}

void ModelRenderer::use_program(const GlProgram& p, const Pass& pass) const {
  glUseProgram(p.id());
  set_view_uniforms(p, pass.view, pass.near_m, pass.far_m);
  glUniform1i(p.uniform("u_color"), 0);
  glUniform1i(p.uniform("u_dist"), 1);
  glUniform2f(p.uniform("u_tex_size"), float(texture_width_), float(texture_height_));
  glUniform1i(p.uniform("u_by_camera"), pass.o.color_by_camera ? 1 : 0);
}

// The k+1 input cameras whose axes are nearest the view's (at most 16).
std::vector<int> ModelRenderer::nearest_cameras(const ViewCamera& view, int k) const {
  const Eigen::Vector3d z = view.world_from_camera.linear().col(2);
  std::vector<std::pair<double, int>> by_angle;
  for (size_t i = 0; i < model_.cameras.size(); ++i)
    if (!model_.cameras[i].texture.empty())
      by_angle.push_back({angle_between(z, model_.cameras[i].world_from_camera.linear().col(2)), int(i)});
  const size_t m = std::min<size_t>({by_angle.size(), size_t(k + 1), 16});
  std::partial_sort(by_angle.begin(), by_angle.begin() + std::ptrdiff_t(m), by_angle.end());
  std::vector<int> list;
  for (size_t i = 0; i < m; ++i) list.push_back(by_angle[i].second);
  return list;
}

// `nearest`: the mesh's fragments ask only the k+1 input cameras whose axes
// are nearest the view's (the k best by angle at a fragment, but near the
// silhouette or for a wide field of view), not every camera: bench render
// measured k+1 both faster and no less sharp than 2k+2.
void ModelRenderer::draw_mesh(const Pass& pass, const GpuMesh& g, size_t triangles, bool nearest, DrawStats& st) const {
  const DrawOptions& o = pass.o;
  const GlProgram& p = programs_->mesh;
  use_program(p, pass);
  const int k = std::clamp(o.selection.cameras, 1, kMaxBlendCameras);
  const std::vector<int> list = nearest ? nearest_cameras(pass.view, k) : std::vector<int>{};
  glUniform1i(p.uniform("u_use_list"), nearest ? 1 : 0);
  if (nearest && !list.empty()) glUniform1iv(p.uniform("u_cam_list[0]"), GLsizei(list.size()), list.data());
  glUniform1i(p.uniform("u_camera_count"), nearest ? int(list.size()) : int(model_.cameras.size()));
  glUniform1i(p.uniform("u_k"), k);
  // The patch mesh lies within about a voxel of the surface the distances
  // were cast against; twice that counts as visible.
  glUniform1f(p.uniform("u_tol"), float(2 * model_.voxel_size_m));
  glUniform1i(p.uniform("u_flat"), 0);
  if (o.wireframe) glPolygonMode(GL_FRONT_AND_BACK, GL_LINE);
  glBindVertexArray(g.vao);
  if (nearest && !o.wireframe) {
    // Depth first (the triangles come in reliability order, not front to
    // back), then each covered pixel is shaded once.
    glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    glUniform1i(p.uniform("u_flat"), 1);
    glDrawElements(GL_TRIANGLES, GLsizei(triangles * 3), GL_UNSIGNED_INT, nullptr);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    glUniform1i(p.uniform("u_flat"), 0);
    glDepthFunc(GL_LEQUAL);
  }
  glDrawElements(GL_TRIANGLES, GLsizei(triangles * 3), GL_UNSIGNED_INT, nullptr);
  glDepthFunc(GL_LESS);
  if (o.wireframe) glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
  st.triangles = triangles;
}

// The octree's selection, the reliable patch triangles first (with
// mesh_reliability: a prefix, most reliable first) and the billboards of
// the facets they leave out; then the billboards, instanced.
void ModelRenderer::draw_billboards(const Pass& pass, DrawStats& st) {
  const DrawOptions& o = pass.o;
  const ViewCamera& view = pass.view;
  SelectionOptions so = o.selection;
  so.near_m = pass.near_m;
  LodOptions lo = o.lod;
  lo.backface_cos = so.backface_cos;
  if (!so.frustum_cull || !so.backface_cull) lo.enabled = false;  // "draw everything" means every model facet
  st.lod = hierarchy_.select(view, lo, pass.near_m, candidates_);
  if (o.mesh_reliability > 0 && has_mesh()) {
    const float R = float(o.mesh_reliability);
    const size_t n = size_t(std::partition_point(triangle_reliability_.begin(), triangle_reliability_.end(),
                                                 [&](float r) { return r >= R; }) -
                            triangle_reliability_.begin());
    if (n) draw_mesh(pass, meshes_[0], n, true, st);
    const auto& least = hierarchy_.least_reliability();
    const size_t before = candidates_.size();
    std::erase_if(candidates_, [&](uint32_t i) { return least[i] >= R; });
    st.facets_on_mesh = before - candidates_.size();
  }
  const GlProgram& p = programs_->billboard;
  use_program(p, pass);
  st.selection = select_facets(FacetSet{hierarchy_.facets(), hierarchy_.facet_cameras(), &candidates_}, model_.cameras,
                               view, so, instances_);
  st.selection.facets = model_.facets.size();
  const Eigen::Vector3d up = -view.world_from_camera.linear().col(1);
  glUniform3f(p.uniform("u_up"), float(up.x()), float(up.y()), float(up.z()));
  glUniform1f(p.uniform("u_scale"), float(std::max(o.billboard_scale, std::sqrt(3.0))));
  glUniform1i(p.uniform("u_clip"), o.depth_clip ? 1 : 0);
  glUniform1f(p.uniform("u_clip_scale"), float(o.clip_scale));
  const int probe = nearest_camera(model_, view);
  glUniform1i(p.uniform("u_probe"), probe);
  // The view from an input camera's own centre (a training view redrawn).
  const bool exact = probe >= 0 && (model_.cameras[size_t(probe)].world_from_camera.translation() - view.eye()).norm() <=
                                        1e-6 * bounds_radius(model_);
  glUniform1i(p.uniform("u_probe_exact"), exact ? 1 : 0);
  glUniform1i(p.uniform("u_refine"), std::max(0, o.refine_steps));
  // In a silhouette-only model the hull is the geometry, and clipping against it is meaningful.
  glUniform1i(p.uniform("u_clip_fuzzy"), o.clip_fuzzy || !has_reliable_ ? 1 : 0);
  const Eigen::Vector3d fwd = view.world_from_camera.linear().col(2);
  glUniform3f(p.uniform("u_view_forward"), float(fwd.x()), float(fwd.y()), float(fwd.z()));
  glUniform1f(p.uniform("u_view_focal"), float(std::sqrt(view.K.fx * view.K.fy)));
  glUniform1f(p.uniform("u_px_error"), float(std::max(0.0, o.pixel_error)));
  glBindVertexArray(billboard_vao_);
  glBindBuffer(GL_ARRAY_BUFFER, instance_vbo_);
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(instances_.size() * sizeof(FacetInstance)), instances_.data(), GL_STREAM_DRAW);
  if (!instances_.empty()) glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, GLsizei(instances_.size()));
}

// Fitted billboards: sorted far to near by their depth in the view, drawn
// "over" into a half-float copy of the target (the background and
// environment already there), copied back.
Status ModelRenderer::draw_splats(const Pass& pass, const Framebuffer& target, DrawStats& st) {
  const auto where = pass.o.fitted_pass;
  if (where == DrawOptions::FittedPass::kCpu || (where == DrawOptions::FittedPass::kAuto && software_gl_))
    return composite_splats_on_cpu(pass, target, st);
  const size_t stride = size_t(model_.splat_layout.stride()), n = model_.splat_count();
  if (!splat_ssbo_) {  // uploaded when the GL pass first draws (the CPU pass reads the model's own copy)
    glGenBuffers(1, &splat_ssbo_);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, splat_ssbo_);
    glBufferData(GL_SHADER_STORAGE_BUFFER, GLsizeiptr(model_.splats.size() * sizeof(float)), model_.splats.data(),
                 GL_STATIC_DRAW);
    glGenVertexArrays(1, &splat_vao_);
    glBindVertexArray(splat_vao_);
    glGenBuffers(1, &splat_order_vbo_);
    glBindBuffer(GL_ARRAY_BUFFER, splat_order_vbo_);
    glEnableVertexAttribArray(0);
    glVertexAttribIPointer(0, 1, GL_UNSIGNED_INT, sizeof(uint32_t), nullptr);
    glVertexAttribDivisor(0, 1);
    glBindVertexArray(0);
  }
  if (!splat_target_ || splat_target_->width() != target.width() || splat_target_->height() != target.height()) {
    auto fb = Framebuffer::create(target.width(), target.height(), true);
    if (!fb) return std::unexpected(fb.error());
    splat_target_ = std::make_unique<Framebuffer>(std::move(*fb));
  }
  target.blit_to(*splat_target_);
  splat_target_->bind();
  const Eigen::Matrix4f cfw = pass.view.world_from_camera.inverse().matrix().cast<float>();
  const Eigen::Vector4f zrow = cfw.row(2);
  std::vector<std::pair<uint32_t, uint32_t>> keys;
  keys.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    const float* c = &model_.splats[i * stride];
    const float z = zrow[0] * c[0] + zrow[1] * c[1] + zrow[2] * c[2] + zrow[3];
    if (!(z > pass.near_m) || c[4] < 1.f / 255.f) continue;
    uint32_t bits;
    std::memcpy(&bits, &z, 4);
    keys.emplace_back(~bits, uint32_t(i));  // far first: descending z
  }
  radix_sort(keys);
  splat_order_.resize(keys.size());
  for (size_t i = 0; i < keys.size(); ++i) splat_order_[i] = keys[i].second;
  st.selection.facets = n;
  st.selection.drawn = keys.size();
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  const GlProgram& p = programs_->splat;
  glUseProgram(p.id());
  set_view_uniforms(p, pass.view, pass.near_m, pass.far_m);
  glUniform1i(p.uniform("u_stride"), int(stride));
  glUniform1i(p.uniform("u_coeffs"), model_.splat_layout.coeffs());
  glUniform1f(p.uniform("u_pixel_filter"), model_.splat_layout.pixel_filter_px2);
  glUniform2f(p.uniform("u_size"), float(target.width()), float(target.height()));
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, splat_ssbo_);
  glBindVertexArray(splat_vao_);
  glBindBuffer(GL_ARRAY_BUFFER, splat_order_vbo_);
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(splat_order_.size() * sizeof(uint32_t)), splat_order_.data(), GL_STREAM_DRAW);
  if (!splat_order_.empty()) glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, GLsizei(splat_order_.size()));
  glDisable(GL_BLEND);
  glEnable(GL_DEPTH_TEST);
  splat_target_->blit_to(target);
  return {};
}

// The backdrop plate laid "under" what is drawn (colour + (1 - alpha) x
// plate; alpha kept: what the model covers), one full-viewport triangle.
// A camera texture's colour (its top-left w x h, rows top to bottom as
// uploaded), read back through a framebuffer on that layer.
bool ModelRenderer::read_layer(int layer, int w, int h, ImageU8& out) const {
  if (layer < 0 || w > texture_width_ || h > texture_height_) return false;
  GLint was = 0;
  glGetIntegerv(GL_FRAMEBUFFER_BINDING, &was);
  GLuint fbo = 0;
  glGenFramebuffers(1, &fbo);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo);
  glFramebufferTextureLayer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, color_array_, 0, layer);
  const bool ok = glCheckFramebufferStatus(GL_FRAMEBUFFER) == GL_FRAMEBUFFER_COMPLETE;
  if (ok) {
    out = ImageU8(w, h, 4);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, out.data.data());
  }
  glBindFramebuffer(GL_FRAMEBUFFER, GLuint(was));
  glDeleteFramebuffers(1, &fbo);
  return ok;
}

Status ModelRenderer::draw_backdrop(const ImageU8& plate, const Framebuffer& target) {
  const int W = target.width(), H = target.height();
  if (plate.width != W || plate.height != H || plate.channels < 3)
    return fail(fmt::format("backdrop plate is {}x{}x{}, the target {}x{} RGB", plate.width, plate.height, plate.channels, W, H));
  // Rows top to bottom as the CPU pass's image, transmittance 0 (the
  // program draws 1 - a as alpha, which the blend leaves out).
  backdrop_rgba_.resize(size_t(W) * H * 4);
  for (size_t p = 0; p < plate.pixels(); ++p) {
    for (size_t c = 0; c < 3; ++c) backdrop_rgba_[p * 4 + c] = float(plate.data[p * size_t(plate.channels) + c]) * (1.f / 255.f);
    backdrop_rgba_[p * 4 + 3] = 0.f;
  }
  if (!backdrop_texture_ || backdrop_width_ != W || backdrop_height_ != H) {
    if (backdrop_texture_) glDeleteTextures(1, &backdrop_texture_);
    glGenTextures(1, &backdrop_texture_);
    glBindTexture(GL_TEXTURE_2D, backdrop_texture_);
    glTexStorage2D(GL_TEXTURE_2D, 1, GL_RGBA32F, W, H);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    backdrop_width_ = W, backdrop_height_ = H;
  }
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, backdrop_texture_);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
  glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, W, H, GL_RGBA, GL_FLOAT, backdrop_rgba_.data());
  target.bind();
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFuncSeparate(GL_ONE_MINUS_DST_ALPHA, GL_ONE, GL_ZERO, GL_ONE);
  const GlProgram& p = programs_->composited;
  glUseProgram(p.id());
  glUniform1i(p.uniform("u_image"), 0);
  glBindVertexArray(screen_vao_);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glDisable(GL_BLEND);
  glEnable(GL_DEPTH_TEST);
  return {};
}

// Fitted billboards composited on the CPU (front to back, each pixel
// finished at its first opaque layer), then laid "over" the target in one
// full-viewport draw: colour + T x what is there.
Status ModelRenderer::composite_splats_on_cpu(const Pass& pass, const Framebuffer& target, DrawStats& st) {
  SplatCompositeStats cs;
  compositor_->set_pixel_filter(model_.splat_layout.pixel_filter_px2);
  compositor_->composite(model_.splats, model_.splat_layout.coeffs(), pass.view.K, pass.view.world_from_camera, pass.near_m,
                         composited_, threads_, &cs);
  st.fitted_on_cpu = true;
  st.selection.facets = cs.facets;
  st.selection.drawn = cs.drawn;
  const int W = target.width(), H = target.height();
  if (!composited_texture_ || composited_width_ != W || composited_height_ != H) {
    if (composited_texture_) glDeleteTextures(1, &composited_texture_);
    glGenTextures(1, &composited_texture_);
    glBindTexture(GL_TEXTURE_2D, composited_texture_);
    glTexStorage2D(GL_TEXTURE_2D, 1, GL_RGBA32F, W, H);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    composited_width_ = W, composited_height_ = H;
  }
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, composited_texture_);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
  glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, W, H, GL_RGBA, GL_FLOAT, composited_.data());
  target.bind();
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  const GlProgram& p = programs_->composited;
  glUseProgram(p.id());
  glUniform1i(p.uniform("u_image"), 0);
  glBindVertexArray(screen_vao_);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glDisable(GL_BLEND);
  glEnable(GL_DEPTH_TEST);
  return {};
}

}  // namespace s2r
