// The turntable axis and every frame's table angle from the session's own
// images: white dot markers on a dark turntable seen by a fixed RGB-D camera
// (the RealSense bear in ../shared/data). No calibration board needed.
//
//   1. Dots: bright, round, small blobs (OpenCV SimpleBlobDetector) whose
//      surroundings are dark, with a depth measurement around them.
//   2. The table plane: RANSAC (PCL) over the dots' depth points of every
//      frame at once (the camera does not move, the table turns in its own
//      plane), then each dot is placed on the plane exactly where its pixel
//      ray meets it (the depth is only needed to find the plane).
//   3. Dots of every pair of frames matched by a two-point RANSAC over pairs
//      of equal distance: a 2D rigid motion in the plane, kept when enough
//      dots agree.
//   4. One Ceres problem over the table centre c and every frame's angle
//      theta_i (theta_0 = 0): residual R(theta_j - theta_i)(a - c) + c - b for
//      every matched pair of dots (a in frame i, b in frame j), Huber loss.
//
// The axis is the plane's normal pointing to the camera's side (up, out of
// the table), through c; theta_i is the turn of the object from frame 0 to
// frame i about it (right-handed), i.e. the table angle Calibration::
// world_from_camera_at expects. The RMS of the dots' residuals measures it.
#pragma once

#include <vector>

#include "calibrate/calibration.h"
#include "core/camera_model.h"
#include "core/image.h"
#include "core/report.h"

namespace s2r {

struct MarkerOptions {
  double min_area_px = 3, max_area_px = 200;  // dot blob area
  double dark_surround = 90;                  // mean grey of the ring around a dot must stay below this
  double plane_tolerance_m = 0.006;           // RANSAC inlier distance of the table plane
  double match_tolerance_m = 0.004;           // dots that coincide after a motion
  int min_matches = 6;                        // dots a pair of frames must share to count
  int threads = 0;
};

struct MarkerFrameStats {
  int dots = 0;           // blobs kept
  int on_plane = 0;       // of them within the plane tolerance
};

struct MarkerResult {
  TurntableAxis axis;     // frame_angles_deg: theta_i per frame
  Eigen::Vector4d plane = Eigen::Vector4d::Zero();  // n.x + d = 0, camera frame, n up
  std::vector<MarkerFrameStats> frames;
  int matched_pairs = 0;  // pairs of frames that share dots
  double rms_m = 0;       // dot residual after the joint fit
  Report report;
};

// `depth_unit_m`: metres per depth count; depth aligned to colour (same K).
Result<MarkerResult> calibrate_table_markers(const std::vector<ImageU8>& colors, const std::vector<ImageU16>& depths,
                                             double depth_unit_m, const Intrinsics& K, const MarkerOptions& options = {});

// `s2r calibrate markers SESSION --out CAL`: loads the session's colour and
// depth, writes the calibration (colour intrinsics from the session, the
// axis, the frames' angles tied to the session's name) atomically.
Result<Report> run_markers_job(const std::filesystem::path& session, const std::filesystem::path& out,
                               const MarkerOptions& options = {});

}  // namespace s2r
