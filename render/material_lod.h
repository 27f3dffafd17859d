// Material level of detail (Tsutsumi, master's thesis, 2010;
// docs/references.md): texture mapping,
// bump mapping and parallax occlusion mapping (POM) of a relief material,
// chosen per pixel from the normalised viewing distance V against the thesis's
// measured threshold lines
//
//   T(R) = 0.331 R + 59.5 (D = 0),   0.327 R + 64.7 (D = 200),  0.325 R + 68.8 (D = 400),
//          0.324 R + 74.0 (D = 600), 0.327 R + 69.0 (D = 800 and 1000)
//
// (R: pattern repeats, D: relief depth, V: distance, all normalised to 0..1000;
// smaller T = the simpler method sooner). What the thesis measured, and so what
// is switched: a material with relief (D > 0) goes from POM to bump mapping
// at V = T(R, D) (linear in D between the rows); a flat one (D = 0, where POM
// and bump mapping draw the same) from bump to plain texture mapping at
// T(R, 0). Within +-blend of the threshold both methods run and are mixed
// (smoothstep), so the switch does not pop.
//
// Normalisations (ours; the thesis's were its application's ranges):
// V = 1000 (d - near) / (far - near) clamped, d the fragment's distance;
// R = 1000 (repeats - 2) / 8 for 2..10 repeats across the surface (the thesis's
// range); D = 1000 depth / 0.1 for a relief depth of 0..0.1 uv units.
#pragma once

#include <memory>

#include <Eigen/Core>

#include "core/image.h"
#include "core/result.h"
#include "render/framebuffer.h"
#include "trace/raytracer.h"

namespace s2r {

// Eq. 4.1: R and D in 0..1000 (clamped), linear interpolation between the D rows.
double seed_material_threshold(double R, double D);
double normalised_repeats(double repeats);  // R
double normalised_depth(double depth_uv);   // D

struct ReliefMaterial {
  ImageU8 albedo;      // RGB, tiles
  ImageF height;       // 1 channel, 0 (deepest) .. 1 (top), same tiling
  double repeats = 4;  // texture repeats across the surface's uv 0..1
  double depth = 0.05; // relief depth in uv units of one tile
};

// A procedural brick wall: mortar lines 0, bricks 1 with bevelled edges, and
// a speckled albedo. `size` pixels square.
ReliefMaterial brick_material(int size, double repeats, double depth);

// kDistanceMap draws V instead of colour (red: V / 1000, green: the next 8
// bits), for masks of the switch band.
enum class MaterialMethod { kTexture = 0, kBump = 1, kParallax = 2, kLod = 3, kDistanceMap = 4 };

struct MaterialDrawOptions {
  MaterialMethod method = MaterialMethod::kLod;
  double near_m = 0.5, far_m = 30;  // the V normalisation
  double blend = 10;                // half-width of the mixing band, in V units
  int pom_min_layers = 8, pom_max_layers = 48;
  Eigen::Vector3f light_dir{0.3f, 0.8f, 0.4f};  // towards the light
};

struct MaterialDrawStats {
  double frame_ms = 0;
  double threshold = 0;  // T for this material
};

class MaterialRenderer {
 public:
  // Needs a current OpenGL 4.3 context. The mesh's first level, its normals
  // and uvs (tangents are derived per triangle from the uvs).
  static Result<std::unique_ptr<MaterialRenderer>> create(const RtMesh& mesh, const ReliefMaterial& material);
  ~MaterialRenderer();
  MaterialRenderer(const MaterialRenderer&) = delete;
  MaterialRenderer& operator=(const MaterialRenderer&) = delete;
  Result<MaterialDrawStats> draw(const Eigen::Vector3d& eye, const Screen& screen, const Framebuffer& target,
                                 const MaterialDrawOptions& options);
  // Into the bound target, sharing its depth buffer (near/far as the caller's).
  Result<MaterialDrawStats> draw_into_bound(const Eigen::Vector3d& eye, const Screen& screen, double near_m, double far_m,
                                            const MaterialDrawOptions& options);
  double threshold() const { return threshold_; }
  bool flat() const { return flat_; }

 private:
  MaterialRenderer() = default;
  struct Gpu;
  std::unique_ptr<Gpu> gpu_;
  double threshold_ = 0;
  bool flat_ = false;
  float repeats_ = 1, depth_ = 0;
};

// The OpenGL matrix that maps the screen rectangle seen from `eye` onto the
// viewport (right and down orthogonal), with OpenGL's depth mapping between
// near and far. Fails when the eye is on or behind the screen's plane.
Result<Eigen::Matrix4f> off_axis_view_projection(const Eigen::Vector3d& eye, const Screen& screen, double near_m, double far_m);
// A distance to the screen's plane, for a default near plane.
double screen_distance(const Eigen::Vector3d& eye, const Screen& screen);

// The two scenes of the thesis's comparison: a flat board receding from the
// eye, and a "roof" model (rows of gabled roofs, many faces at many angles).
struct MaterialScene {
  RtMesh mesh;
  Eigen::Vector3d eye;
  Screen screen;
};
MaterialScene material_board_scene(int width, int height);
MaterialScene material_roof_scene(int width, int height);

}  // namespace s2r
