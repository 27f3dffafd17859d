// The model the viewer loads (docs/formats.md, "Model"):
//
//   MODEL/model.json        header: version, voxel size, bounds, cameras,
//                           payload files with record counts and CRC-32
//   MODEL/facets.bin        FacetRecord[] (little-endian, 40 bytes each)
//   MODEL/facet_cameras.bin uint32[]: camera indices, FacetRecord ranges into it
//   MODEL/octree.bin        OctreeRecord[] (optional): the surface octree, breadth first
//   MODEL/cameras/NNNN.exr  per-camera RGBA + distance textures
//   MODEL/splats.bin        float[] (optional): the fitted billboards, SplatLayout each
//
// Every payload starts with a 24-byte header: magic "S2RB", payload version,
// record size, record count; and ends with the CRC-32 of everything before.
// Loading rejects a truncated or inconsistent model, naming file and field.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/result.h"

namespace s2r {

inline constexpr int kModelVersion = 1;

struct FacetRecord {
  float center[3];       // world, metres
  float size;            // voxel width w (the billboard is >= sqrt(3) w wide)
  float normal[3];       // unit, or 0 where unknown
  float reliability;     // 0..1 agreement between views
  uint32_t first_camera; // range in facet_cameras
  uint32_t camera_count;
};
static_assert(sizeof(FacetRecord) == 40, "FacetRecord is an on-disk layout");

// One node of the surface octree (reconstruct/octree.h), 52 bytes. Children
// are contiguous at first_child (0xffffffff: a leaf); a node covers the cells
// origin .. origin + 2^(max_level - level) - 1, cell (i,j,k) lying between the
// samples at voxel centres (i..i+1, j..j+1, k..k+1) * voxel.
struct OctreeRecord {
  float vertex[3];        // representative vertex, world metres
  float normal[3];        // normal cone axis (unit)
  float cone;             // cone half-angle, radians, [0, pi]
  float shape_error;      // dE, metres
  int32_t origin[3];      // first cell
  uint32_t first_child;
  uint16_t edge_flags;    // leaves: the 12 cell edges that cross the surface
  uint8_t children;
  uint8_t level;          // 0 = root
};
static_assert(sizeof(OctreeRecord) == 52, "OctreeRecord is an on-disk layout");
inline constexpr uint32_t kNoChild = 0xffffffffu;

// The fitted billboards (reconstruct/splat_fit.h) as stored: per facet
// centre x y z (metres), footprint sigma (metres), opacity (0..1), then the
// colour's spherical-harmonic coefficients, coefficient-major (k * 3 + c),
// (degree + 1)^2 of them per channel.
// The pixel filter of the fitted billboards' image formation (splat_fit.h):
// the variance, in pixels^2, of the Gaussian each footprint is convolved with
// on screen. Models fitted before it had none (model.json without
// "splat_pixel_filter_px2" loads as 0 and draws as it was fitted).
// 0.1, chosen on lego's val split (all 100 views, 1500-s fits, full image:
// 33.10 dB / SSIM 0.974 against 32.54 / 0.971 at 0.3; docs/cli.md).
inline constexpr float kSplatPixelFilterPx2 = 0.1f;

struct SplatLayout {
  int sh_degree = 0;
  float pixel_filter_px2 = kSplatPixelFilterPx2;
  int coeffs() const { return (sh_degree + 1) * (sh_degree + 1); }
  int stride() const { return 5 + 3 * coeffs(); }  // floats per facet
};

struct ModelCamera {
  Intrinsics intrinsics;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  std::string texture;  // relative path of the RGBA+depth texture, may be empty
  int session_frame = -1;
};

struct Model {
  double voxel_size_m = 0;
  // The name of the session the cameras' frames are of (session.json's
  // "name"); a frame of another session is never one of the model's cameras.
  // Empty in models written before it was kept.
  std::string session;
  Eigen::AlignedBox3d bounds;
  std::vector<ModelCamera> cameras;
  std::vector<FacetRecord> facets;
  std::vector<uint32_t> facet_cameras;
  std::vector<OctreeRecord> octree;  // empty when not built
  int octree_max_level = 0;
  std::optional<std::string> patch_mesh;  // relative PLY path
  std::optional<std::string> surface_mesh;  // relative PLY path: the fused surface
  std::optional<std::string> environment;  // relative path
  // The capture's background (RGB in [0, 1]): the one its photos were
  // composited on (white for NeRF-synthetic) or the fit's backdrop colour.
  // Drawing the model defaults to it; empty: black.
  std::optional<std::array<float, 3>> background;
  // Relative PNG path: the backdrop plate (reconstruct/backdrop_plate.h), the
  // fixed camera's view behind the object, drawn behind frames of the
  // capture seen from its cameras. Empty where the backdrop is uniform or
  // not static.
  std::optional<std::string> backdrop;
  SplatLayout splat_layout;
  std::vector<float> splats;  // fitted billboards, splat_layout.stride() floats each; empty when not fitted
  size_t splat_count() const { return splats.size() / size_t(splat_layout.stride()); }
};

// What load_model reads: all of the model, or all but the octree (a fitted
// view never needs it; load_octree reads it where billboards first draw).
struct ModelLoad {
  bool octree = true;
};
Result<Model> load_model(const std::filesystem::path& dir, ModelLoad what = {});
// The octree of a model loaded without it (nothing where the model has none
// or `m` already holds it), checked as load_model checks it.
Status load_octree(const std::filesystem::path& dir, Model& m);
// Whether model.json names fitted billboards (reads only the header; false
// where it cannot be read: load_model says why).
bool model_has_fit(const std::filesystem::path& dir);
// The model's backdrop plate (RGB, its cameras' size), or nothing where it
// has none; an error where the file is missing, unreadable or of another size.
Result<std::optional<ImageU8>> load_backdrop(const Model& model, const std::filesystem::path& dir);
// A splats.bin payload alone (a snapshot of a fit), in the model's format;
// load checks it holds whole facets of `layout` with valid values.
Status save_splat_payload(const std::filesystem::path& file, const std::vector<float>& splats);
Result<std::vector<float>> load_splat_payload(const std::filesystem::path& file, const SplatLayout& layout);
Status save_model(const std::filesystem::path& dir, const Model& model);

}  // namespace s2r
