// The drawing core of `s2r view`, `s2r render` and `s2r eval` (microfacet
// billboarding, Yamazaki et al. 2002): one class, the same shaders for the window and the headless context.
//
// Billboard pass: every selected facet (render/facet_selection.h) is a square
// sqrt(3) w wide through its centre, facing the eye. Each fragment projects
// its world point into the facet's chosen cameras (pinhole + lens model),
// and with depth clipping takes a camera's texel only where |d - D| < tol:
// d the fragment's distance from that camera, D the distance stored in the
// camera's texture, tol = clip_scale w (sqrt(3)/2 w, the farthest a point of
// the voxel lies from its centre; the paper's w/2 leaves holes where the
// surface clips a voxel corner), widened where the texel's on-screen
// misplacement |d - D| sin(theta) stays under pixel_error (at theta = 0 the
// view is the camera's and any depth is exact). Passing texels are refined
// along the view ray (refine_steps). Facets without measured depth
// (reliability 0) skip the clip in models that have depth. The passing
// cameras are blended with the
// facet's weights (renormalised). Where a camera sees through the fragment
// (D > d + tol, or its ray hits nothing) the fragment is empty space and is
// discarded; the input camera most like the view is asked the same
// question, whichever facet is drawn (free-space carving). No passing
// camera: discarded too, so the billboards behind show through.
// Camera distance images are extended by one pixel around silhouettes at
// load (the fused surface sits slightly inside the photo's edge pixels).
//
// Mesh pass (the textured-mesh baseline): the model's patch mesh, each
// fragment textured from its k best cameras by angle among those whose
// stored distance agrees with the fragment's within 2 w (visible), same
// weights; where no camera sees it, the nearest camera by angle whose image
// contains it (a baseline mesh has no holes).
//
// Hybrid (billboards with mesh_reliability R > 0, the detail the LOD switches
// to where geometry is reliable): the patch triangles with a facet of
// reliability >= R within a base voxel of a corner are drawn first, through
// the mesh pass but asking only the k+1 cameras whose axes are nearest the
// view's; then the billboards of every selected facet or node whose facets
// do not all reach R. The triangles are uploaded most reliable first, so
// those drawn are one prefix of the index buffer.
//
// Views are drawn through their lens model too (vertices are distorted), so
// rendering at an input camera's view reproduces its photo pixel for pixel.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "core/image.h"
#include "core/result.h"
#include "render/facet_lod.h"
#include "render/facet_selection.h"
#include "render/framebuffer.h"

namespace s2r {

// What the billboard pass reads of a camera, shared with the web viewer's
// export (render/web_export.cpp): the largest |x/z|^2 the camera's lens
// model is trusted at (its image corners' directions, 20 % to spare), and
// its distances with one pixel around every hit given the nearest hit's
// distance (a silhouette pixel the fused surface misses through its centre).
double camera_field_r2(const Intrinsics& K);
void fill_silhouette_distance(ImageF& distance);

class GlossyRenderer;
class GlProgram;
class SplatCompositor;

struct DrawOptions {
  // kMesh: the octree's patch mesh; kSurface: the fused surface mesh;
  // kSplats: the fitted billboards (reconstruct --fit).
  enum class Geometry { kBillboards, kMesh, kSurface, kSplats };
  Geometry geometry = Geometry::kBillboards;
  bool depth_clip = true;
  bool color_by_camera = false;  // flat colour per chosen camera (the paper's figure 6(d))
  bool wireframe = false;        // mesh pass: edges only
  double billboard_scale = 1.7320508075688772;  // width / w, >= sqrt(3)
  double clip_scale = 0.8660254037844386;  // clip threshold / w: sqrt(3)/2, the farthest a
                                           // point of the voxel lies from its centre
  double pixel_error = 0.5;      // clip widens where the texel's misplacement stays under this (px); 0: fixed clip
  bool clip_fuzzy = false;       // also clip facets without measured depth (reliability 0) in models
                                 // that have depth (silhouette-only models are always clipped)
  int refine_steps = 2;          // texel refinement along the view ray (0 = the paper's texel at the billboard point)
  SelectionOptions selection;
  LodOptions lod;                // octree level of detail of the billboards (render/facet_lod.h)
  // Billboards only: > 0 draws the patch mesh where the geometry is reliable
  // (its triangles near a facet of at least this reliability) and leaves
  // out the billboards whose facets all reach it; 0: billboards everywhere.
  double mesh_reliability = 0;
  float background[3] = {0.f, 0.f, 0.f};
  // The backdrop plate (RGB, the target's size; not owned): drawn behind the
  // model in place of `background`, for frames of the model's own capture
  // seen from its cameras (Model::backdrop). Null: the background colour.
  const ImageU8* backdrop = nullptr;
  // kSplats: where the fitted billboards are composited. kAuto: on the CPU
  // (reconstruct/splat_composite.h: front to back, stopping at the first
  // opaque layer) when the OpenGL renderer is itself software (llvmpipe,
  // softpipe, SwiftShader), else the GL pass. Both are the fit's image formation.
  enum class FittedPass { kAuto, kGl, kCpu };
  FittedPass fitted_pass = FittedPass::kAuto;
  double near_m = 0.01, far_m = 100.0;
  // Drawn first into the same depth buffer: the panorama as backdrop and the
  // glossy floor and props (render/glossy_renderer.h). Not owned.
  GlossyRenderer* environment = nullptr;
};

// "billboards", "mesh", "surface", "fitted" (the command line's names).
constexpr const char* geometry_name(DrawOptions::Geometry g) {
  switch (g) {
    case DrawOptions::Geometry::kMesh: return "mesh";
    case DrawOptions::Geometry::kSurface: return "surface";
    case DrawOptions::Geometry::kSplats: return "fitted";
    default: return "billboards";
  }
}

struct DrawStats {
  SelectionStats selection;   // billboards
  LodStats lod;
  size_t triangles = 0;       // mesh (with mesh_reliability: the reliable triangles drawn)
  size_t facets_on_mesh = 0;  // with mesh_reliability: selected billboards left to the mesh
  bool fitted_on_cpu = false;  // kSplats: composited on the CPU (DrawOptions::fitted_pass)
  double cpu_ms = 0;          // selection + upload + submit
  double frame_ms = 0;        // until the image is finished (glFinish)
  bool environment_drawn = false, envmap_bound = false;
  bool backdrop_drawn = false;  // the plate behind the model
  bool backdrop_own_photo = false;  // at an input camera itself (billboards, meshes): its own photo instead of the plate
};

class ModelRenderer {
 public:
  // Needs a current OpenGL 4.3+ context. Loads the camera textures (RGBA and
  // distance) into texture arrays and the patch mesh when the model has one;
  // for a model with fitted billboards, only when billboards or a mesh are
  // first drawn (a fitted view never reads the photos).
  static Result<std::unique_ptr<ModelRenderer>> create(Model model, const std::filesystem::path& model_dir,
                                                       int threads = 0);
  ~ModelRenderer();
  ModelRenderer(const ModelRenderer&) = delete;
  ModelRenderer& operator=(const ModelRenderer&) = delete;

  // Draws into `target` (cleared to the background, alpha 0 where nothing is
  // drawn). The view's image size must equal the target's.
  Result<DrawStats> draw(const ViewCamera& view, const DrawOptions& options, const Framebuffer& target);

  const Model& model() const { return model_; }
  bool has_splats() const { return !model_.splats.empty(); }
  bool has_textures() const { return has_textures_; }  // camera images: what billboards and meshes are textured from
  // The model names that mesh (once loaded: it has triangles).
  bool has_mesh(DrawOptions::Geometry g = DrawOptions::Geometry::kMesh) const {
    const bool surface = g == DrawOptions::Geometry::kSurface;
    if (!photo_passes_) return (surface ? model_.surface_mesh : model_.patch_mesh).has_value();
    return meshes_[surface ? 1 : 0].triangles > 0;
  }
  size_t texture_bytes() const { return texture_bytes_; }  // loaded so far (0 until billboards or a mesh are drawn)
  bool photo_passes_loaded() const { return photo_passes_.has_value(); }
  Status load_photo_passes();  // what billboards and meshes need, now (draw() does it when first needed)
  const FacetHierarchy& hierarchy() const { return hierarchy_; }

 private:
  ModelRenderer() = default;
  struct Programs;
  struct Pass;
  struct GpuMesh {
    unsigned vao = 0, vbo = 0, ibo = 0;
    size_t triangles = 0;
  };
  // draw()'s steps.
  Status clear_and_environment(const Pass& pass, const Framebuffer& target, DrawStats& st);
  void bind_model_state() const;
  void use_program(const GlProgram& p, const Pass& pass) const;
  std::vector<int> nearest_cameras(const ViewCamera& view, int k) const;
  void draw_mesh(const Pass& pass, const GpuMesh& g, size_t triangles, bool nearest, DrawStats& st) const;
  void draw_billboards(const Pass& pass, DrawStats& st);
  Status draw_splats(const Pass& pass, const Framebuffer& target, DrawStats& st);
  Status composite_splats_on_cpu(const Pass& pass, const Framebuffer& target, DrawStats& st);
  Status draw_backdrop(const ImageU8& plate, const Framebuffer& target);
  Status load_photo_passes_once();
  bool read_layer(int layer, int w, int h, ImageU8& out) const;
  Model model_;
  std::filesystem::path dir_;
  bool has_textures_ = false;
  std::optional<Status> photo_passes_;  // loaded (or failed), once
  std::vector<int> camera_layer_;       // per model camera: its texture's layer, -1 none
  ImageU8 own_photo_;                   // an input camera's photo read back, behind its own view
  std::unique_ptr<Programs> programs_;
  unsigned color_array_ = 0, distance_array_ = 0;
  unsigned facet_ssbo_ = 0, camera_ssbo_ = 0;
  unsigned billboard_vao_ = 0, instance_vbo_ = 0;
  GpuMesh meshes_[2];  // patch mesh (most reliable triangles first), fused surface
  std::vector<float> triangle_reliability_;  // per patch-mesh triangle, as uploaded (descending)
  size_t texture_bytes_ = 0;
  bool has_reliable_ = false;  // any facet with measured depth
  int texture_width_ = 0, texture_height_ = 0;
  FacetHierarchy hierarchy_;
  std::vector<uint32_t> candidates_;
  std::vector<FacetInstance> instances_;
  unsigned splat_ssbo_ = 0, splat_vao_ = 0, splat_order_vbo_ = 0;
  unsigned screen_vao_ = 0;
  std::unique_ptr<Framebuffer> splat_target_;
  std::vector<uint32_t> splat_order_;
  // The CPU pass: its compositor (buffers kept between frames), its image
  // and the texture it is laid over the target from.
  bool software_gl_ = false;
  int threads_ = 0;
  std::unique_ptr<SplatCompositor> compositor_;
  std::vector<float> composited_;
  unsigned composited_texture_ = 0;
  int composited_width_ = 0, composited_height_ = 0;
  std::vector<float> backdrop_rgba_;
  unsigned backdrop_texture_ = 0;
  int backdrop_width_ = 0, backdrop_height_ = 0;
};

}  // namespace s2r
