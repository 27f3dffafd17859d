#include "capture/ground_truth.h"

#include "core/json_fields.h"

namespace s2r {
namespace fs = std::filesystem;

Result<GroundTruth> load_ground_truth(const fs::path& session_dir) {
  const fs::path path = session_dir / "ground_truth" / "rig.json";
  std::error_code ec;
  if (!fs::exists(path, ec)) return fail(ErrorCode::not_found, "'" + path.string() + "': no ground truth");
  auto j = parse_json_file(path);
  if (!j) return std::unexpected(j.error());
  try {
    FieldReader doc(*j, path.string());
    check_format_header(doc, "s2r.synth_truth", 1);
    GroundTruth t;
    t.scene = doc.string("scene");
    t.layout = doc.string("layout") == "camera_centre" ? Layout::kCameraCentre : Layout::kObjectCentre;
    t.color = intrinsics_from(doc.at("color_intrinsics"));
    t.depth = intrinsics_from(doc.at("depth_intrinsics"));
    t.color_from_depth = doc.rigid("color_from_depth");
    t.axis_dir_camera = vec3_from(doc, "axis_dir_camera");
    t.axis_point_camera = vec3_from(doc, "axis_point_camera");
    if (doc.has("world_from_board")) t.world_from_board = doc.rigid("world_from_board");
    FieldReader frames = doc.at("frames");
    for (size_t i = 0; i < frames.array_size(); ++i) {
      t.true_angle_deg.push_back(frames.index(i).number("table_angle_true_deg"));
      t.world_from_camera.push_back(frames.index(i).rigid("world_from_camera"));
    }
    return t;
  } catch (const FormatError& e) {
    return fail(ErrorCode::format, e.what());
  }
}

std::optional<std::vector<Eigen::Isometry3d>> ground_truth_poses(const fs::path& session_dir, size_t frames) {
  auto truth = load_ground_truth(session_dir);
  if (!truth || truth->world_from_camera.size() != frames) return std::nullopt;
  return std::move(truth->world_from_camera);
}

}  // namespace s2r
