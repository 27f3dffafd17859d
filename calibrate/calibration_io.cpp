#include <cmath>
#include <numbers>

#include "calibrate/calibration.h"
#include "core/atomic_file.h"
#include "core/json_fields.h"

namespace s2r {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

json sensor_json(const SensorCalibration& s) {
  return {{"intrinsics", intrinsics_to_json(s.intrinsics)}, {"rms_px", s.rms_px}, {"views", s.views}};
}

SensorCalibration sensor_from(const FieldReader& r) {
  return {intrinsics_from(r.at("intrinsics")), r.number("rms_px"), static_cast<int>(r.integer_or("views", 0))};
}

}  // namespace

Eigen::Isometry3d Calibration::world_from_camera_at(double angle_deg, Layout layout) const {
  const TurntableAxis a = axis.value_or(TurntableAxis{});
  const double sign = layout == Layout::kObjectCentre ? -1.0 : 1.0;
  return rotation_about_axis(a.direction_camera, a.point_camera, sign * angle_deg * std::numbers::pi / 180);
}

size_t mask_off_table(ImageU16& depth, double unit, const Intrinsics& K, const Eigen::Isometry3d& color_from_depth,
                      const TurntableAxis& axis) {
  if (!(axis.table_radius_m > 0)) return 0;
  size_t masked = 0;
  for (int y = 0; y < depth.height; ++y)
    for (int x = 0; x < depth.width; ++x) {
      uint16_t& d = depth.data[size_t(y) * depth.width + x];
      if (!d) continue;
      const auto p = K.unproject({double(x), double(y)}, d * unit);
      if (p && axis.over_table(color_from_depth * *p)) continue;
      d = 0;
      ++masked;
    }
  return masked;
}

Status save_calibration(const fs::path& path, const Calibration& c) {
  json j = {{"format", "s2r.calibration"}, {"version", kCalibrationVersion}};
  if (c.color) j["color"] = sensor_json(*c.color);
  if (c.depth) j["depth"] = sensor_json(*c.depth);
  if (c.color_from_depth)
    j["color_from_depth"] = {{"transform", rigid_to_json(*c.color_from_depth)}, {"rms", c.color_from_depth_rms}};
  if (c.axis) {
    const auto& a = *c.axis;
    j["turntable_axis"] = {
        {"direction_camera", {a.direction_camera.x(), a.direction_camera.y(), a.direction_camera.z()}},
        {"point_camera", {a.point_camera.x(), a.point_camera.y(), a.point_camera.z()}},
        {"rms_m", a.rms_m},
        {"step_angles_deg", a.step_angles_deg}};
    if (a.table_radius_m > 0) j["turntable_axis"]["table_radius_m"] = a.table_radius_m;
    if (!a.frame_angles_deg.empty())
      j["turntable_axis"]["frames"] = {{"session", a.frames_session}, {"angles_deg", a.frame_angles_deg}};
  }
  return write_file_atomic(path, dump_json(j));
}

Result<Calibration> load_calibration(const fs::path& path) {
  auto j = parse_json_file(path);
  if (!j) return std::unexpected(j.error());
  try {
    FieldReader doc(*j, path.string());
    check_format_header(doc, "s2r.calibration", kCalibrationVersion);
    Calibration c;
    if (doc.has("color")) c.color = sensor_from(doc.at("color"));
    if (doc.has("depth")) c.depth = sensor_from(doc.at("depth"));
    if (doc.has("color_from_depth")) {
      FieldReader e = doc.at("color_from_depth");
      c.color_from_depth = e.rigid("transform");
      c.color_from_depth_rms = e.number("rms");
    }
    if (doc.has("turntable_axis")) {
      FieldReader a = doc.at("turntable_axis");
      TurntableAxis axis;
      axis.direction_camera = vec3_from(a, "direction_camera");
      const double n = axis.direction_camera.norm();
      if (std::abs(n - 1) > 1e-6) a.error("direction_camera", "must be a unit vector (norm " + std::to_string(n) + ")");
      axis.point_camera = vec3_from(a, "point_camera");
      axis.rms_m = a.number("rms_m");
      if (a.has("step_angles_deg")) {
        FieldReader s = a.at("step_angles_deg");
        for (size_t i = 0; i < s.array_size(); ++i) {
          if (!s.raw()[i].is_number()) s.error("element " + std::to_string(i) + " is not a number");
          axis.step_angles_deg.push_back(s.raw()[i].get<double>());
        }
      }
      if (a.has("table_radius_m")) {
        axis.table_radius_m = a.number("table_radius_m");
        if (axis.table_radius_m < 0) a.error("table_radius_m", "must not be negative");
      }
      if (a.has("frames")) {
        FieldReader fr = a.at("frames");
        axis.frames_session = fr.string("session");
        FieldReader s = fr.at("angles_deg");
        for (size_t i = 0; i < s.array_size(); ++i) {
          if (!s.raw()[i].is_number() || !std::isfinite(s.raw()[i].get<double>()))
            s.error("element " + std::to_string(i) + " is not a finite number");
          axis.frame_angles_deg.push_back(s.raw()[i].get<double>());
        }
      }
      c.axis = axis;
    }
    return c;
  } catch (const FormatError& e) {
    return fail(e.what());
  }
}

}  // namespace s2r
