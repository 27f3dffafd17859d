// The synthetic turntable rig: ray-cast (Embree) scenes on a virtual
// turntable with known intrinsics (with lens distortion), table axis, angles
// and depth-to-colour extrinsic. Writes a session in the standard format plus
// ground_truth/ (exact poses, exact depth, labels, geometry). Deterministic
// for a given seed, whatever the thread count.
//
// Depth sensor model (structured-light / stereo-like):
//   - z noise N(0, (k z^2)^2), quantised to `unit_m`;
//   - holes where the correlation window straddles a depth discontinuity
//     (thin strands, silhouettes): any of 4 neighbour rays at +-0.75 px misses
//     or differs by more than 2 % of z;
//   - holes at grazing incidence (angle to the normal above `grazing_deg`);
//   - optional independent per-pixel dropout.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <optional>
#include <vector>

#include <Eigen/Geometry>

#include "capture/ground_truth.h"
#include "capture/session.h"
#include "core/camera_model.h"
#include "core/image.h"
#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct SynthOptions {
  std::string scene = "bunny";
  int views = 24;
  uint64_t seed = 7;
  int width = 640, height = 480;
  int spp = 4;                    // colour samples per pixel: 1 or 4
  double depth_noise_k = 0.0015;  // sigma_z = k z^2 (metres)
  double depth_unit_m = 0.001;
  double grazing_deg = 78;
  double dropout = 0;         // probability of a random depth hole
  double color_noise = 1.0;   // sigma in 8-bit levels
  double exposure = 1.0;      // radiance gain before the 8-bit response (clips above 1)
  double table_error_deg = 0; // table turns this much less than commanded per step
  int threads = 0;            // 0 = all cores
  std::filesystem::path data_dir;  // empty = s2r::data_dir()

  Status validate() const;
};

struct SynthView {
  ImageU8 color;            // RGB, distorted colour camera
  ImageU16 depth;           // depth camera, sensor model applied
  ImageF gt_depth_color;    // exact z in the colour camera (0 = nothing)
  ImageF gt_depth;          // exact z in the depth camera
  ImageU8 labels;           // depth camera: 0 nothing, 1 surface, 2 strand
  size_t rays = 0;
};

class SynthRig {
 public:
  static Result<std::unique_ptr<SynthRig>> create(const SynthOptions& options);
  ~SynthRig();

  const SynthOptions& options() const;
  Layout layout() const;
  const Intrinsics& color_intrinsics() const;
  const Intrinsics& depth_intrinsics() const;
  const Eigen::Isometry3d& color_from_depth() const;
  Eigen::Isometry3d world_from_camera_at(double table_angle_deg) const;
  Eigen::Isometry3d world_from_board() const;  // the "board" scene's chessboard frame
  // Colour camera pose at view i (world = object frame for object-centre
  // scenes, the room for camera-centre scenes).
  Eigen::Isometry3d world_from_camera(int view) const;
  double commanded_angle_deg(int view) const;
  double true_angle_deg(int view) const;
  // Table axis in the colour camera frame at angle 0.
  Eigen::Vector3d axis_dir_camera() const;
  Eigen::Vector3d axis_point_camera() const;

  SynthView render(int view) const;
  // At any table angle (the simulated capture devices); `noise_key` seeds the noise.
  SynthView render_at(double table_angle_deg, uint64_t noise_key) const;
  Status write_geometry(const std::filesystem::path& dir) const;

 private:
  struct Impl;
  explicit SynthRig(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// The whole job behind `s2r synth`: session + ground_truth/ in `out`.
Result<Report> synth_session(const SynthOptions& options, const std::filesystem::path& out);

}  // namespace s2r
