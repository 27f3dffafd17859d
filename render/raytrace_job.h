// Scenes and the job behind `s2r raytrace` (Mochizuki and Makino, "An efficient
// ray tracing with LOD control by human eyesight for immersive display
// system"; docs/references.md).
//
// The immersive layout is a CAVE-like room of three screens, front, right and
// floor, the walls of a cube (edge 3 m; x right, y up, -z forward, floor at
// y = 0, the cube centred on x = z = 0). Each wall is rendered for the tracked
// eye position through its own off-axis image plane, and the eye frame of the
// visual field follows the gaze, not the walls.
//
// The paper's four scenes place 8 objects (the Stanford bunny, simplified to
// N_max = 5804 triangles with levels down to N_min = 500, as the paper's cow)
// and one point light: A mirrors spread over every screen, B diffuse spread,
// C mirrors on the front screen only, D diffuse on the front screen only.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/mesh.h"
#include "core/report.h"
#include "core/result.h"
#include "trace/meshes.h"
#include "trace/raytracer.h"

namespace s2r {

inline constexpr double kCaveSize = 3.0;

// front, right, floor; each `pixels` square.
std::vector<Screen> cave_screens(int pixels, double size = kCaveSize);
Eigen::Vector3d cave_default_eye(double size = kCaveSize);
// The three walls unfolded into one picture: front top left, right beside
// it, floor below the front. Images must be the same square size.
ImageU8 unfold_cave(const std::vector<ImageU8>& walls);

struct SeedSceneOptions {
  char scene = 'A';  // A..D
  size_t n_max = 5804, n_min = 500;
  int levels = 6;
};
// `base` is the object every slot holds (the bunny for the bench).
Result<RtScene> seed_scene(const Mesh& base, const SeedSceneOptions& options);

// A reconstructed model's patch mesh (or fused surface mesh) as one object,
// coloured per vertex from the camera that sees the vertex most head-on
// (distance images decide visibility, within 2 voxels).
Result<RtObject> model_object(const std::filesystem::path& model_dir, bool surface_mesh, size_t n_min, int levels);

struct RaytraceJob {
  std::string scene = "C";              // A..D, when neither mesh nor model is given
  std::filesystem::path mesh;           // a PLY (vertex colours used when present)
  std::filesystem::path model;          // a reconstructed model
  bool surface_mesh = false;            // the model's fused surface instead of the patch mesh
  std::string layout;                   // "cave" or "view"; empty: cave for A..D, view otherwise
  std::optional<Eigen::Vector3d> eye;   // default: CAVE centre at head height, or in front of the object
  std::optional<Eigen::Vector3d> gaze;  // default: forward (CAVE) or the view's centre
  int size = 256;                       // pixels per CAVE wall side, or the view's width
  int reflect_max = 3;
  bool field_lod = true;
  bool compare_full = true;  // render without LOD too: time ratio, PSNR inside the central field
  size_t n_max = 5804, n_min = 500;
  int levels = 6;
  int threads = 0;
  std::filesystem::path out;
  std::filesystem::path data_dir;  // empty: s2r::data_dir()
  bool quiet = false;

  // The options' own ranges, an error naming the field ("size: must be
  // within 8..8192"); what depends on the scene is checked by the job.
  Status validate() const;
};

// What run_raytrace_job measured, typed; report.json is to_report().
struct RaytraceSummary {
  std::string layout;                      // cave or view
  TraceStats trace;                        // rays, pixels, what the visual field left out
  double render_seconds = 0, bvh_build_seconds = 0;
  size_t triangles_full_detail = 0, triangles_coarsest = 0;
  // Against the full-detail render (compare_full with field LOD): PSNR in
  // the central field and over all pixels (infinite where identical).
  std::optional<double> psnr_central_field_db, psnr_all_pixels_db, time_ratio_lod_over_full;
  double seconds = 0;
  Report report;

  const Report& to_report() const { return report; }
  std::string brief() const { return report.brief(); }
};

Result<RaytraceSummary> run_raytrace_job(const RaytraceJob& job);

// Images of one layout rendered by one tracer; what the job and the bench share.
struct LayoutRender {
  std::vector<TraceResult> walls;
  double seconds = 0;
  TraceStats stats;
};
LayoutRender render_layout(const RayTracer& tracer, const std::vector<Screen>& screens, const Eigen::Vector3d& eye,
                           const TraceOptions& options);
// PSNR of `test` against `reference` over the pixels whose level is in
// [lo, hi] (+inf when identical; NaN when no pixel qualifies).
double psnr_where(const LayoutRender& test, const LayoutRender& reference, double lo, double hi);

}  // namespace s2r
