#include "reconstruct/frame_inputs.h"

#include "capture/ground_truth.h"
#include "reconstruct/poses.h"

namespace s2r {
namespace fs = std::filesystem;

Result<FramePoses> resolve_frame_poses(const Session& s, const fs::path& poses_file, const fs::path& calibration_file) {
  FramePoses fp;
  fp.world_from_camera.resize(s.frames.size());
  if (!poses_file.empty()) {
    auto p = load_poses(poses_file);
    if (!p) return std::unexpected(p.error());
    for (const auto& f : p->frames) {
      if (f.index < 0 || size_t(f.index) >= s.frames.size())
        return fail(ErrorCode::invalid, "'" + poses_file.string() + "': frame " + std::to_string(f.index) +
                                            " is not in the session (" + std::to_string(s.frames.size()) + " frames)");
      if (!f.flagged) fp.world_from_camera[size_t(f.index)] = f.world_from_camera;
    }
    fp.kind = PoseSource::poses_file;
    fp.source = "poses file " + poses_file.filename().string();
    return fp;
  }
  bool given = !s.frames.empty();
  for (const auto& f : s.frames) given = given && f.world_from_camera.has_value();
  if (given) {
    for (size_t i = 0; i < s.frames.size(); ++i) fp.world_from_camera[i] = s.frames[i].world_from_camera;
    fp.kind = PoseSource::given;
    fp.source = "given";
    return fp;
  }
  if (!calibration_file.empty()) {
    auto c = load_calibration(calibration_file);
    if (!c) return std::unexpected(c.error());
    if (!c->axis)
      return fail(ErrorCode::invalid, "'" + calibration_file.string() +
                                          "' has no turntable axis: calibrate its axis (s2r calibrate axis), or give poses");
    for (size_t i = 0; i < s.frames.size(); ++i)
      fp.world_from_camera[i] = c->world_from_camera_at(c->frame_angle_deg(s, i), s.layout);
    fp.kind = PoseSource::calibrated_axis;
    fp.source = c->has_measured_angles(s) ? "measured table angles (markers) about the calibrated axis"
                                          : "table angles about the calibrated axis";
    return fp;
  }
  if (auto truth = ground_truth_poses(s.root, s.frames.size())) {
    for (size_t i = 0; i < s.frames.size(); ++i) fp.world_from_camera[i] = (*truth)[i];
    fp.kind = PoseSource::ground_truth;
    fp.source = "ground truth (synthetic rig)";
    return fp;
  }
  return fail(ErrorCode::not_found, "session '" + s.root.string() +
                                        "' has no camera poses: give poses (s2r register) or a calibration with a "
                                        "turntable axis");
}

DepthSensorModel resolve_depth_sensor(const Session& s, const Calibration* cal) {
  DepthSensorModel d;
  if (s.depth) {
    d.intrinsics = s.depth->intrinsics;
    d.color_from_depth = s.depth->color_from_depth;
    d.unit_m = s.depth->unit_m;
  }
  if (cal && cal->depth) d.intrinsics = cal->depth->intrinsics;
  if (cal && cal->color_from_depth) d.color_from_depth = *cal->color_from_depth;
  return d;
}

std::optional<Intrinsics> resolve_color_intrinsics(const Session& s, const Frame& f, const Calibration* cal) {
  if (cal && cal->color) return cal->color->intrinsics;
  return s.color_intrinsics(f);
}

}  // namespace s2r
