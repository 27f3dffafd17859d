// A calibrated capture handed to other tools (docs/formats.md, "Exports"):
//
//   colmap      cameras.txt, images.txt, points3D.txt and images/: COLMAP's
//               text model (cam_from_world as quaternion w x y z + translation,
//               OpenCV's camera axes, pixel centres at (i + 0.5, j + 0.5), so
//               cx and cy move by +0.5). One camera per distinct intrinsics:
//               PINHOLE without distortion, OPENCV with k1 k2 p1 p2 (FULL_OPENCV
//               when k3 is set). Points: the depth frames fused on a voxel grid
//               (one point per occupied voxel, its mean position and colour),
//               each with the frames whose depth saw it as its track; none for
//               a capture without depth.
//   nerfstudio  transforms.json (nerfstudio / instant-ngp): per-frame fl_x fl_y
//               cx cy w h k1 k2 p1 p2 (k3), camera-to-world in OpenGL axes
//               (x right, y up, z back), cx and cy with pixel centres at
//               i + 0.5; images/, and masks/ where the session has mattes.
//
// The poses are the ones every stage resolves (reconstruct/frame_inputs.h: a
// poses file, the frames' given poses, a calibrated axis, the rig's truth).
// The export is written into a temporary folder beside OUT and renamed into
// place when whole; OUT must not exist or be empty.
#pragma once

#include <filesystem>
#include <string>

#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct ExportJob {
  std::string format;  // colmap | nerfstudio
  std::filesystem::path session, poses, calibration, out;
  double point_voxel_m = 0;  // colmap points: fusion grid (0: 1/256 of the depth points' extent)
  int max_points = 200000;   // colmap points: at most this many (the most observed first)
};

Result<Report> export_session(const ExportJob& job);

}  // namespace s2r
