// Per-camera depth refined by photo-consistency, for captures without depth.
//
// The visual hull is the largest shape the silhouettes allow: it fills every
// concavity that no silhouette shows (between legs, under a chin, inside a
// cup). Each camera's depth is therefore searched behind the hull's surface
// along its own pixels' rays, as a plane sweep does (Collins, "A space-sweep
// approach to true multi-image matching", 1996), scored by normalized
// cross-correlation of a window against the nearest cameras (the mean of the
// best two: a neighbour that sees another surface there does not veto), and
// kept only where the match is textured, strong and clearly better than at the
// hull itself. What is kept carves the hull (space in front of a refined depth
// is empty: Kutulakos and Seitz, "A theory of shape by space carving", 2000);
// a pixel with no clear match carves nothing.
//
// OpenCV (remap, box filters) is confined to photo_depth.cpp.
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"

namespace s2r {

struct PhotoView {
  const ImageU8* color = nullptr;  // RGB or grey
  const ImageU8* mask = nullptr;   // the silhouette (non-zero inside), or null
  Intrinsics K;
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
};

struct PhotoDepthParams {
  double step_m = 0;          // between depth hypotheses (> 0)
  double range_m = 0;         // how far behind the hull a pixel's depth is searched (> 0)
  int window = 7;             // the correlation window's side, odd
  int neighbours = 4;         // cameras compared with, nearest in viewing direction first
  double max_angle_deg = 60;  // between the reference's and a neighbour's view of the object
  double min_ncc = 0.7;       // the mean of the best two correlations a kept depth needs
  double min_gain = 0.1;      // over the best correlation within a step of the hull
  double min_texture = 0.01;  // the window's standard deviation on 0..1 grey
};

struct PhotoDepthStats {
  size_t pixels_on_hull = 0;     // with a hull distance
  size_t pixels_untextured = 0;  // the window too flat to match
  size_t pixels_at_silhouette = 0;  // the window crosses the silhouette
  size_t pixels_unmatched = 0;   // no correlation above min_ncc, or fewer than two neighbours
  size_t pixels_at_hull = 0;     // the best match within a step of the hull
  size_t pixels_behind_hull = 0; // kept deeper than the hull by more than a step
  size_t pixels_ambiguous = 0;   // deeper, but not min_gain better than at the hull
  size_t planes = 0;             // hypotheses swept
  double shift_sum_m = 0;        // summed over pixels_behind_hull
  int neighbours_used = 0;
  PhotoDepthStats& operator+=(const PhotoDepthStats& o);
};

// The nearest cameras to `ref` in viewing direction of `centre` (the angle
// between the rays from each camera centre to it), within max_angle_deg and
// not the same direction (under 1 degree), nearest first.
std::vector<size_t> photo_neighbours(const std::vector<PhotoView>& views, size_t ref, const Eigen::Vector3d& centre,
                                     const PhotoDepthParams& p);

// Camera `ref`'s distance along each pixel's ray (metres) where photo-
// consistency finds the surface at or behind the hull's distance `hull`
// (metres along the ray, 0 where the hull is not seen); 0 where no clear
// match was found. Never in front of the hull.
ImageF photo_consistent_depth(const std::vector<PhotoView>& views, size_t ref, const std::vector<size_t>& neighbours,
                              const ImageF& hull, const PhotoDepthParams& p, PhotoDepthStats* stats = nullptr);

}  // namespace s2r
