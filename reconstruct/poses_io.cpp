#include "core/atomic_file.h"
#include "core/json_fields.h"
#include "reconstruct/poses.h"

namespace s2r {
namespace fs = std::filesystem;
using nlohmann::json;

Status save_poses(const fs::path& path, const Poses& p) {
  json frames = json::array();
  for (const auto& f : p.frames) {
    json j = {{"index", f.index}, {"world_from_camera", rigid_to_json(f.world_from_camera)},
              {"residual_rms_m", f.residual_rms_m}, {"flagged", f.flagged}};
    if (!f.note.empty()) j["note"] = f.note;
    frames.push_back(j);
  }
  json doc = {{"format", "s2r.poses"}, {"version", kPosesVersion}, {"session", p.session},
              {"rms_m", p.rms_m}, {"frames", frames}};
  return write_file_atomic(path, dump_json(doc));
}

Result<Poses> load_poses(const fs::path& path) {
  auto j = parse_json_file(path);
  if (!j) return std::unexpected(j.error());
  try {
    FieldReader doc(*j, path.string());
    check_format_header(doc, "s2r.poses", kPosesVersion);
    Poses p;
    p.session = doc.string_or("session", "");
    p.rms_m = doc.number_or("rms_m", 0);
    FieldReader frames = doc.at("frames");
    for (size_t i = 0; i < frames.array_size(); ++i) {
      FieldReader f = frames.index(i);
      FramePose fp;
      fp.index = static_cast<int>(f.integer("index"));
      if (fp.index != static_cast<int>(i))
        f.error("index", "expected " + std::to_string(i) + " (frames numbered from 0 without gaps), got " +
                             std::to_string(fp.index));
      fp.world_from_camera = f.rigid("world_from_camera");
      fp.residual_rms_m = f.number_or("residual_rms_m", 0);
      fp.flagged = f.boolean_or("flagged", false);
      fp.note = f.string_or("note", "");
      p.frames.push_back(fp);
    }
    return p;
  } catch (const FormatError& e) {
    return fail(e.what());
  }
}

}  // namespace s2r
