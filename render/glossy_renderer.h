// OpenGL drawing of glossy materials from the multi-scale environment map
// (Okumura 2003; docs/references.md), for the same scene description the ray
// tracer reads (RtScene), so the two can be compared pixel for pixel.
//
// Per fragment: the reflection r of the view ray about the shading normal,
// the roughness from the material's roughness texture (bilinear, per pixel:
// the thesis could only set it per vertex) or its constant, the Phong exponent
// L = roughness_to_exponent(roughness) and the map's radius for it, and one
// trilinear read of the 3D texture at r lambda(L). Colour:
//   (1 - k_g) k_d albedo E(n, lambda ~ 0) + k_g E(r, lambda(L))
// where E is the map; the diffuse part reads the map's roughest shell about
// the normal in place of the ray tracer's point lights (this renderer has no
// lights). The thesis's simplification is kept and stated: the lobe is not
// tested for occlusion (the object does not reflect itself), as in the ray
// tracer's glossy term. Pixels the objects do not cover show the panorama
// (nearest pixel, as the ray tracer's misses) or the scene's background.
//
// Only when needed: without a glossy material no environment map is built,
// uploaded or bound; DrawStats say so (`envmap_bound`).
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/report.h"
#include "core/result.h"
#include "render/envmap.h"
#include "render/framebuffer.h"
#include "render/material_lod.h"
#include "trace/raytracer.h"

namespace s2r {

struct GlossyDrawStats {
  double frame_ms = 0;
  bool envmap_bound = false;
  size_t envmap_texture_bytes = 0;
  size_t triangles = 0;
};

class GlossyRenderer {
 public:
  // Needs a current OpenGL 4.3+ context. `envmap` is used only when some
  // material is glossy (and then must be given).
  static Result<std::unique_ptr<GlossyRenderer>> create(const RtScene& scene, std::shared_ptr<const EnvironmentMap> envmap);
  ~GlossyRenderer();
  GlossyRenderer(const GlossyRenderer&) = delete;
  GlossyRenderer& operator=(const GlossyRenderer&) = delete;

  // The screen seen from `eye` (the ray tracer's Screen: any off-axis
  // rectangle), into `target` of the screen's size, cleared first.
  Result<GlossyDrawStats> draw(const Eigen::Vector3d& eye, const Screen& screen, const Framebuffer& target);
  // Into the bound, already cleared target (another renderer's pass shares
  // its depth buffer): depth written with the same near/far mapping as the
  // model renderer's, so the objects and the model occlude each other.
  Result<GlossyDrawStats> draw_into_bound(const Eigen::Vector3d& eye, const Screen& screen, double near_m, double far_m);
  bool needs_envmap() const { return needs_envmap_; }
  // World directions -> panorama directions (the panorama is y up; a table
  // frame is z up). Identity by default.
  void set_environment_from_world(const Eigen::Matrix3d& rotation) { env_from_world_ = rotation; }
  const Eigen::AlignedBox3d& bounds() const { return bounds_; }
  // A relief-mapped object drawn after the glossy ones (the floor with
  // material LOD: texture / bump / parallax occlusion mapping per pixel).
  void set_relief(std::unique_ptr<MaterialRenderer> relief, const MaterialDrawOptions& options, const Eigen::AlignedBox3d& box) {
    relief_ = std::move(relief);
    relief_options_ = options;
    bounds_.extend(box);
  }

 private:
  GlossyRenderer() = default;
  struct Gpu;
  std::unique_ptr<Gpu> gpu_;
  bool needs_envmap_ = false;
  size_t envmap_bytes_ = 0, triangles_ = 0;
  Eigen::Matrix3d env_from_world_ = Eigen::Matrix3d::Identity();
  Eigen::AlignedBox3d bounds_;
  std::unique_ptr<MaterialRenderer> relief_;
  MaterialDrawOptions relief_options_;
};

// The pinhole part of a calibrated view as a Screen (lens distortion is not
// applied to the environment pass).
Screen screen_for_view(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera);

// True when some object's material has a glossy weight above 0.
bool scene_is_glossy(const RtScene& scene);

}  // namespace s2r

namespace s2r {

// The check: a unit glossy sphere (k_g = 1, no diffuse, no lights)
// whose roughness comes per pixel from `roughness` (first channel / 255, mapped
// by latitude: v from the south pole 0 to the north pole 1), in front of the
// panorama, drawn `size` x `size` by the GL renderer from `map` and by the ray
// tracer with the exact lobe. Errors are |GL - traced| in grey levels (of 255)
// per channel over the sphere's pixels, and over its grazing pixels (view
// angle above 75 degrees).
struct GlossyComparison {
  ImageU8 gl, traced;
  double mean_error = 0, max_error = 0, grazing_mean_error = 0, grazing_max_error = 0;
  size_t pixels = 0, grazing_pixels = 0;
  double gl_frame_ms = 0, trace_seconds = 0;
  size_t envmap_texture_bytes = 0;
};
// Roughness ramping 0 -> 1 `bands` times from the south pole to the north:
// smooth stretches and per-pixel jumps (the thesis's per-vertex roughness
// distorted where it changed quickly).
ImageU8 roughness_ramps(int bands);
Result<GlossyComparison> compare_glossy_sphere(std::shared_ptr<const Panorama> panorama, std::shared_ptr<const EnvironmentMap> map,
                                               const ImageU8& roughness, int size, int threads = 0);

}  // namespace s2r

namespace s2r {

// What `s2r render` and `s2r view` put around a model: the panorama as
// backdrop, a floor under the object (the plane through the model's lowest
// point along `up`, three object radii each way) and glossy spheres. The
// environment map is loaded from `envmap`, or built from the panorama, only
// when something is glossy; otherwise nothing is built or bound and the
// report says so.
struct EnvironmentSetup {
  std::filesystem::path panorama;
  std::filesystem::path envmap;                 // a prebuilt map; empty: built when needed
  bool clamp = false;                           // clamp non-finite panorama pixels (with a warning)
  double floor_roughness = -1;                  // < 0: no floor
  std::filesystem::path floor_roughness_texture;  // per-pixel roughness (first channel / 255), 4 tiles per side
  // A relief floor instead (brick wall material, render/material_lod.h): R and
  // D in Tsutsumi's 0..1000, drawn with material LOD; not glossy. R < 0: none.
  double floor_relief_R = -1, floor_relief_D = 200;
  Eigen::Vector3f floor_colour{0.45f, 0.45f, 0.45f};
  float floor_glossy = 0.5f;                    // k_g of the floor (0: matte, no map needed)
  struct Prop {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double radius = 0.05, roughness = 0.2;
  };
  std::vector<Prop> props;                      // glossy spheres (k_g = 1)
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();  // the world's up: the table frame is z up
  EnvmapOptions envmap_options;
};

struct PreparedEnvironment {
  std::unique_ptr<GlossyRenderer> renderer;
  std::shared_ptr<const EnvironmentMap> map;
  double envmap_seconds = 0;  // built or loaded
  std::string envmap_source;  // "built", "loaded" or "not needed"
  std::vector<std::string> warnings;
};

// What was built, loaded or left out, into a stage's report.
void report_environment(const PreparedEnvironment& env, Report& report);

// Needs a current OpenGL context.
Result<PreparedEnvironment> prepare_environment(const EnvironmentSetup& setup, const Eigen::AlignedBox3d& model_bounds);
// Rows: a horizontal axis, up, and their cross product: world -> panorama (y up).
Eigen::Matrix3d environment_from_world(const Eigen::Vector3d& up);

}  // namespace s2r
