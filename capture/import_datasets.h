// Importers: real data sets (as in ../shared/data) -> sessions.
//
//   stanford   a Stanford .conf + its PLY range scans: one frame per scan,
//              points/NNNN.ply, the conf pose as world_from_camera
//   middlebury a folder with *_par.txt (K, R, t per image): colour frames with
//              per-frame intrinsics and given poses
//   realsense  D435 colour + aligned 16-bit depth (mm), fixed intrinsics
//   7scenes    colour, depth (65535 -> no measurement), 4x4 camera-to-world
//   nerf       a transforms.json (NeRF's Blender scenes, nerfstudio, instant-ngp):
//              camera_angle_x or fl_x/fl_y/cx/cy with k1 k2 p1 p2 (k3), global or
//              per frame; camera-to-world in OpenGL axes turned into OpenCV's;
//              an RGBA photo becomes its colour on the background (white unless
//              given) plus its alpha as the frame's matte. Each split is imported
//              on its own into the same world frame (no rescaling, no centring).
//   colmap     a COLMAP sparse model, text or binary (cameras, images,
//              points3D): SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV;
//              cam_from_world inverted, pixel centres moved to integers.
//
// Frames keep the source's own listing order; `source` keeps the original name.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>

#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct ImportOptions {
  int stride = 1;      // take every n-th view
  int max_frames = 0;  // 0 = all
  std::string split;   // nerf: transforms_<split>.json; empty: transforms.json, else transforms_train.json
  std::optional<std::array<float, 3>> background;  // nerf: what RGBA photos are composited on (default white)
  std::filesystem::path images;  // colmap: the images' folder (default DIR/images, else beside the model)
};

Result<Report> import_dataset(const std::string& kind, const std::filesystem::path& path,
                              const std::filesystem::path& out, const ImportOptions& options);

}  // namespace s2r
