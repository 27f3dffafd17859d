// CPU ray tracer (Mochizuki and Makino; docs/references.md): Whitted-style recursion on
// Embree BVHs with point lights, shadows, mirror reflection, refraction and
// Phong materials over textured or vertex-coloured meshes, multithreaded over
// tiles; and Mochizuki and Makino's visual-field level of detail per primary ray.
//
// Level of detail, per primary ray (trace/visual_field.h gives the level):
//   - level 0: not traced, the pixel gets the background;
//   - reflections and refractions allowed: floor(level * reflect_max);
//     secondary and shadow rays inherit the primary ray's level; a branch
//     cut by the budget returns the background;
//   - mesh detail per object: N = level (N_max - N_min) + N_min triangles
//     (eq. 10), served by the coarsest prebuilt level that has at least N.
// Switching detail costs nothing per ray: every object's levels are built
// once (one BVH each, sharing the vertices), and for each level quantum
// (level rounded up to 1/32) a top-level scene instances the level each
// object needs. A ray only picks which top-level scene to intersect. The paper
// changed polygon counts per frame and measured a slowdown where objects
// filled every screen; prebuilding is what avoids it (`s2r bench raytrace`).
//
// Exact and deterministic: no random sampling; each pixel's colour depends
// only on its own ray, whatever the thread count or tiling. Secondary rays
// start at the hit point pushed off the surface by a few float ULPs
// (Waechter and Binder, Ray Tracing Gems ch. 6), which stays correct at any
// scene scale, so there is no scale-dependent epsilon.
//
// The same tracer is the reference renderer: the synthetic rig
// (capture/synth_rig.cpp) renders its ground-truth colour and depth through
// it, with round curves for the fuzzy object's strands, procedural albedo for
// its printed textures and a directional light without shadows.
//
// Shading: local = ambient k_a kd + sum over unshadowed lights of
// I (kd max(0, n.l) + ks max(0, r.v)^s), computed as exp(s log(r.v)). The
// pixel is (1 - k_r - k_t - k_g) local + k_r R + k_t T + k_g G, G the
// environment's exact Phong lobe about the mirror direction (no occlusion
// test on the lobe, as in Okumura 2003); under total internal reflection the k_t
// share goes to the reflected ray. Shadow rays treat every
// object as opaque. Colours are linear; images are stored 8-bit, clamped.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/image.h"
#include "core/result.h"
#include "trace/phong_reference.h"
#include "trace/visual_field.h"

namespace s2r {

struct RtMaterial {
  Eigen::Vector3f diffuse{0.7f, 0.7f, 0.7f};   // kd (times vertex colour and texture)
  Eigen::Vector3f specular{0.3f, 0.3f, 0.3f};  // ks
  float shininess = 40;                        // Phong exponent
  float ambient = 0.1f;                        // ka
  float reflect = 0;                           // k_r
  float transmit = 0;                          // k_t
  float ior = 1.5f;                            // index of refraction inside
  float glossy = 0;                            // k_g: weight of the environment's Phong lobe
  float glossy_exponent = 100;                 // its exponent (any value >= 0; 1e6 is fine)
  int texture = -1;                            // RtScene::textures index (needs uvs)
  // Per-pixel roughness for the glossy lobe: RtScene::textures index, the first
  // channel / 255 (bilinear, like `texture`); the exponent at each hit is then
  // roughness_to_exponent(roughness) (trace/phong_reference.h) instead of glossy_exponent.
  int roughness_texture = -1;
  // Optional procedural colour (a printed pattern): called at every hit with
  // the world point and the ray's unit direction; multiplies kd like a texture.
  std::function<Eigen::Vector3f(const Eigen::Vector3f& p, const Eigen::Vector3f& dir)> albedo;
};

// A triangle mesh with its levels of detail: index buffers into one vertex
// array, levels[0] the finest (N_max), levels.back() the coarsest (N_min).
struct RtMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3f> normals;  // per vertex; empty: flat shading
  std::vector<Eigen::Vector3f> colors;   // per vertex, linear 0..1; empty: white
  std::vector<Eigen::Vector2f> uvs;      // per vertex; needed by a texture
  std::vector<std::vector<Eigen::Vector3i>> levels;

  size_t triangles(int level = 0) const { return levels.empty() ? 0 : levels[level].size(); }
  Status validate(const std::string& what) const;
};

// Simplified index buffers (meshoptimizer), from `faces` down to about
// `n_min` triangles in `count` geometric steps; element 0 is `faces` itself.
// Levels that the simplifier cannot shrink further (topology) are dropped,
// so the chain may be shorter than `count`; triangle counts strictly fall.
Result<std::vector<std::vector<Eigen::Vector3i>>> build_lod_chain(const std::vector<Eigen::Vector3f>& vertices,
                                                                  const std::vector<Eigen::Vector3i>& faces, size_t n_min,
                                                                  int count);

struct RtObject {
  std::string name;
  RtMesh mesh;
  RtMaterial material;
  Eigen::Isometry3d world_from_object = Eigen::Isometry3d::Identity();
};

// Round linear curves (strands, fibres): segment s joins points[s] and
// points[s + 1], each point x, y, z (world) and radius. Shaded with the
// curve's surface normal at the hit; kd times the segment's colour.
struct RtCurves {
  std::string name;
  std::vector<Eigen::Vector4f> points;
  std::vector<uint32_t> segments;
  std::vector<Eigen::Vector3f> colors;  // per segment, linear 0..1; empty: white
  RtMaterial material;                  // no texture maps (curves have no uvs)

  Status validate() const;
};

struct PointLight {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // directional: the direction towards the light
  Eigen::Vector3f intensity{1, 1, 1};
  bool directional = false;  // at infinity (sunlight, a distant lamp)
  bool shadows = true;       // false: lights every surface facing it, occluded or not
};

// What a ray meets first (RayTracer::intersect).
struct RtHit {
  bool found = false;
  float t = 0;         // along the direction as given (not normalised)
  int object = -1;     // RtScene::objects index, or -1
  int curves = -1;     // RtScene::curves index, or -1
  int prim = -1;       // triangle or segment
  Eigen::Vector3f normal = Eigen::Vector3f::Zero();  // geometric, world frame, unit
};

struct RtScene {
  std::vector<RtObject> objects;
  std::vector<RtCurves> curves;  // one level: the same in every level of detail
  std::vector<PointLight> lights;
  Eigen::Vector3f background{0.05f, 0.06f, 0.08f};
  // Optional: rays that leave the scene see it, and glossy materials reflect
  // its exact Phong lobe (phong_reference.h; brute force per hit: this is the
  // reference the environment map is measured against, not a fast path).
  std::shared_ptr<const Panorama> environment;
  std::vector<ImageU8> textures;  // RGB, sRGB-free: read as linear 0..1
};

// An image plane: pixel (x, y) has its centre at
// corner + (x + 0.5)/width * right + (y + 0.5)/height * down, and its ray runs
// from the eye through that point. A CAVE wall is one; so is a pinhole view.
struct Screen {
  std::string name;
  Eigen::Vector3d corner = Eigen::Vector3d::Zero();
  Eigen::Vector3d right = Eigen::Vector3d::UnitX();
  Eigen::Vector3d down = -Eigen::Vector3d::UnitY();
  int width = 0, height = 0;

  static Screen pinhole(const Eigen::Vector3d& eye, const Eigen::Vector3d& forward, const Eigen::Vector3d& up,
                        double fov_y_deg, int width, int height);
  Eigen::Vector3d point(double x, double y) const {
    return corner + (x + 0.5) / width * right + (y + 0.5) / height * down;
  }
  Status validate() const;
};

struct TraceOptions {
  int reflect_max = 3;    // Reflect_max
  bool field_lod = false; // false: the full render (every ray level 1)
  EyeFrame gaze;          // the eye frame the levels are measured in
  int threads = 0;        // 0 = all cores
  int tile = 16;          // pixels per tile side
};

struct TraceStats {
  size_t pixels = 0;
  size_t outside_field = 0;  // level 0: background without tracing
  size_t central = 0;        // level 1
  size_t primary = 0, secondary = 0, shadow = 0;
  size_t depth_cut = 0;      // reflection/refraction branches cut by the level's budget
  size_t total_internal = 0; // refractions turned into reflections
  size_t misses = 0;         // rays that left the scene
  size_t empty_tiles_pixels = 0;  // pixels of tiles whose rays all pass beside the scene: not traced
  size_t glossy_lobes = 0;   // exact environment lobes integrated
  double seconds = 0;
  std::array<size_t, 33> rays_per_quantum{};  // primary rays by level quantum (32 = full detail)

  void add(const TraceStats& o);
};

struct TraceResult {
  ImageF color;  // RGB, linear
  ImageF level;  // per pixel, the primary ray's level
  TraceStats stats;
};

class RayTracer {
 public:
  static constexpr int kQuanta = 32;

  // Builds every object's levels and the top-level scenes. Fails on an
  // invalid mesh, material or light, naming the object.
  static Result<std::unique_ptr<RayTracer>> create(RtScene scene);
  ~RayTracer();

  TraceResult render(const Screen& screen, const Eigen::Vector3d& eye, const TraceOptions& options) const;
  // One primary ray at a given level (> 0), for tests and probes.
  // `lights`, when given, replace the scene's for this ray (a light that
  // moves between frames of one scene, as the rig's does relative to the
  // turning object).
  Eigen::Vector3f trace(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double level, int reflect_max,
                        TraceStats* stats = nullptr, const std::vector<PointLight>* lights = nullptr) const;
  // The first surface along origin + t dir, 0 <= t < t_far, at full detail.
  RtHit intersect(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir,
                  float t_far = std::numeric_limits<float>::infinity()) const;

  // Which level each object uses for a ray of this level (eq. 10).
  std::vector<int> detail_for(double level) const;
  const RtScene& scene() const;
  double build_seconds() const;  // all BVHs, every level
  size_t top_scenes() const;     // distinct level combinations built

 private:
  struct Impl;
  explicit RayTracer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Linear RGB -> 8-bit, clamped to [0, 1], rounded.
ImageU8 to_u8(const ImageF& linear);
// Ray origin pushed off a surface along its (unit) normal by a few ULPs of
// the coordinates: robust at every scene scale.
Eigen::Vector3f offset_ray_origin(const Eigen::Vector3f& p, const Eigen::Vector3f& n);
// Refraction of unit `d` at a surface with unit normal `n` facing against d,
// eta = n_from / n_to. False on total internal reflection.
bool refract_dir(const Eigen::Vector3f& d, const Eigen::Vector3f& n, float eta, Eigen::Vector3f* out);

}  // namespace s2r
