// Importers: real data sets (as in ../shared/data) -> sessions.
//
//   stanford   a Stanford .conf + its PLY range scans: one frame per scan,
//              points/NNNN.ply, the conf pose as world_from_camera
//   middlebury a folder with *_par.txt (K, R, t per image): colour frames with
//              per-frame intrinsics and given poses
//   realsense  D435 colour + aligned 16-bit depth (mm), fixed intrinsics
//   7scenes    colour, depth (65535 -> no measurement), 4x4 camera-to-world
//
// Frames keep the source's own listing order; `source` keeps the original name.
#pragma once

#include <filesystem>
#include <string>

#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct ImportOptions {
  int stride = 1;      // take every n-th view
  int max_frames = 0;  // 0 = all
};

Result<Report> import_dataset(const std::string& kind, const std::filesystem::path& path,
                              const std::filesystem::path& out, const ImportOptions& options);

}  // namespace s2r
