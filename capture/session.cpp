#include "capture/session.h"

#include <cmath>
#include <cstdio>
#include <fstream>

#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/json_fields.h"
#include "core/paths.h"

namespace s2r {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kFormat = "s2r.session";

json frame_to_json(const Frame& f) {
  json j = {{"index", f.index},
            {"table_angle_commanded_deg", f.table_angle_commanded_deg},
            {"table_angle_reported_deg", f.table_angle_reported_deg},
            {"timestamp_ns", f.timestamp_ns}};
  if (!f.color.empty()) j["color"] = f.color;
  if (!f.depth.empty()) j["depth"] = f.depth;
  if (!f.points.empty()) j["points"] = f.points;
  if (!f.mask.empty()) j["mask"] = f.mask;
  if (!f.source.empty()) j["source"] = f.source;
  if (f.exposure_us > 0) j["exposure_us"] = f.exposure_us;
  if (f.world_from_camera) j["world_from_camera"] = rigid_to_json(*f.world_from_camera);
  if (f.intrinsics) j["intrinsics"] = intrinsics_to_json(*f.intrinsics);
  return j;
}

Frame frame_from(const FieldReader& r) {
  Frame f;
  f.index = static_cast<int>(r.integer("index"));
  f.table_angle_commanded_deg = r.number_or("table_angle_commanded_deg", 0);
  f.table_angle_reported_deg = r.number_or("table_angle_reported_deg", f.table_angle_commanded_deg);
  f.timestamp_ns = r.integer_or("timestamp_ns", 0);
  f.color = r.string_or("color", "");
  f.depth = r.string_or("depth", "");
  f.points = r.string_or("points", "");
  f.mask = r.string_or("mask", "");
  if (!f.mask.empty() && f.color.empty()) r.error("mask", "a matte needs the frame's colour image");
  f.source = r.string_or("source", "");
  f.exposure_us = r.number_or("exposure_us", 0);
  if (r.has("world_from_camera")) f.world_from_camera = r.rigid("world_from_camera");
  if (r.has("intrinsics")) f.intrinsics = intrinsics_from(r.at("intrinsics"));
  if (f.color.empty() && f.depth.empty() && f.points.empty())
    r.error("frame has no colour, depth or points file");
  return f;
}

json session_to_json(const Session& s) {
  json j = {{"format", kFormat}, {"version", kSessionVersion}, {"name", s.name},
            {"source", s.source},
            {"layout", s.layout == Layout::kObjectCentre ? "object_centre" : "camera_centre"}};
  json dev = json::object();
  if (s.color) {
    const auto& c = *s.color;
    dev["color"] = {{"driver", c.driver}, {"device", c.device}, {"pixel_format", c.pixel_format},
                    {"intrinsics", intrinsics_to_json(c.intrinsics)},
                    {"exposure_us", c.exposure_us}, {"gain", c.gain}};
  }
  if (s.depth) {
    const auto& d = *s.depth;
    dev["depth"] = {{"driver", d.driver}, {"device", d.device},
                    {"intrinsics", intrinsics_to_json(d.intrinsics)}, {"unit_m", d.unit_m},
                    {"color_from_depth", rigid_to_json(d.color_from_depth)},
                    {"aligned_to_color", d.aligned_to_color}};
  }
  if (s.turntable) dev["turntable"] = {{"driver", s.turntable->driver}, {"device", s.turntable->device}};
  j["devices"] = dev;
  j["notes"] = s.notes;
  if (s.background) j["background"] = *s.background;
  json frames = json::array();
  for (const auto& f : s.frames) frames.push_back(frame_to_json(f));
  j["frames"] = frames;
  return j;
}

void check_file_field(const Session& s, const FieldReader& fr, const char* key,
                      const std::string& rel, bool check_images,
                      const std::optional<Intrinsics>& expect) {
  if (rel.empty()) return;
  auto full = resolve_inside(s.root, rel);
  if (!full) fr.error(key, full.error().message);
  std::error_code ec;
  if (!fs::exists(*full, ec)) fr.error(key, "'" + rel + "': file not found");
  if (fs::file_size(*full, ec) == 0) fr.error(key, "'" + rel + "': file is empty");
  if (!check_images || std::string(key) == "points") return;
  auto info = probe_image(*full);
  if (!info) fr.error(key, info.error().message);
  if (expect && (info->width != expect->width || info->height != expect->height))
    fr.error(key, "'" + rel + "' is " + std::to_string(info->width) + "x" +
                      std::to_string(info->height) + " but the intrinsics say " +
                      std::to_string(expect->width) + "x" + std::to_string(expect->height));
}

Session session_from(const json& j, const fs::path& dir, const SessionLoadOptions& opts) {
  FieldReader doc(j, (dir / "session.json").string());
  check_format_header(doc, kFormat, kSessionVersion);
  Session s;
  s.root = dir;
  s.name = doc.string_or("name", dir.filename().string());
  s.source = doc.string_or("source", "");
  const std::string layout = doc.string_or("layout", "object_centre");
  if (layout == "object_centre") s.layout = Layout::kObjectCentre;
  else if (layout == "camera_centre") s.layout = Layout::kCameraCentre;
  else doc.error("layout", "expected \"object_centre\" or \"camera_centre\", got \"" + layout + "\"");
  if (doc.has("devices")) {
    FieldReader dev = doc.at("devices");
    if (dev.has("color")) {
      FieldReader c = dev.at("color");
      ColorSensor cs;
      cs.driver = c.string_or("driver", "");
      cs.device = c.string_or("device", "");
      cs.pixel_format = c.string_or("pixel_format", "");
      cs.intrinsics = intrinsics_from(c.at("intrinsics"));
      cs.exposure_us = c.number_or("exposure_us", 0);
      cs.gain = c.number_or("gain", 0);
      s.color = cs;
    }
    if (dev.has("depth")) {
      FieldReader d = dev.at("depth");
      DepthSensor ds;
      ds.driver = d.string_or("driver", "");
      ds.device = d.string_or("device", "");
      ds.intrinsics = intrinsics_from(d.at("intrinsics"));
      ds.unit_m = d.positive("unit_m");
      if (d.has("color_from_depth")) ds.color_from_depth = d.rigid("color_from_depth");
      ds.aligned_to_color = d.boolean_or("aligned_to_color", false);
      s.depth = ds;
    }
    if (dev.has("turntable")) {
      FieldReader t = dev.at("turntable");
      s.turntable = TurntableInfo{t.string_or("driver", ""), t.string_or("device", "")};
    }
  }
  if (doc.has("background")) {
    const json& b = doc.raw()["background"];
    if (!b.is_array() || b.size() != 3) doc.error("background", "expected [r, g, b] in [0, 1]");
    std::array<float, 3> rgb{};
    for (size_t c = 0; c < 3; ++c) {
      if (!b[c].is_number() || !(b[c].get<double>() >= 0 && b[c].get<double>() <= 1))
        doc.error("background", "expected [r, g, b] in [0, 1]");
      rgb[c] = b[c].get<float>();
    }
    s.background = rgb;
  }
  if (doc.has("notes")) {
    FieldReader n = doc.at("notes");
    for (size_t i = 0; i < n.array_size(); ++i)
      if (n.raw()[i].is_string()) s.notes.push_back(n.raw()[i].get<std::string>());
  }
  FieldReader frames = doc.at("frames");
  const size_t n = frames.array_size();
  for (size_t i = 0; i < n; ++i) {
    FieldReader fr = frames.index(i);
    Frame f = frame_from(fr);
    if (f.index != static_cast<int>(i))
      fr.error("index", "expected " + std::to_string(i) +
                            " (frames are numbered from 0 without gaps), got " +
                            std::to_string(f.index));
    if (!f.color.empty() && !s.color && !f.intrinsics)
      fr.error("color", "frame has a colour image but there is no colour sensor nor frame intrinsics");
    if (!f.depth.empty() && !s.depth)
      fr.error("depth", "frame has a depth image but devices.depth is missing");
    check_file_field(s, fr, "color", f.color, opts.check_images, s.color_intrinsics(f));
    check_file_field(s, fr, "depth", f.depth, opts.check_images,
                     s.depth ? std::optional<Intrinsics>(s.depth->intrinsics) : std::nullopt);
    check_file_field(s, fr, "points", f.points, false, std::nullopt);
    check_file_field(s, fr, "mask", f.mask, opts.check_images, s.color_intrinsics(f));
    s.frames.push_back(std::move(f));
  }
  return s;
}

// Frames the journal has beyond session.json (a capture killed between the two writes).
Status merge_journal(Session& s, const SessionLoadOptions& opts) {
  const fs::path jpath = s.root / "session.journal";
  std::ifstream in(jpath);
  if (!in) return {};
  std::string line;
  int lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.empty()) continue;
    json j;
    try {
      j = json::parse(line);
    } catch (const json::parse_error&) {
      // A torn last line from a kill mid-append: the frame was not acknowledged.
      if (in.peek() == EOF) break;
      return fail(jpath.string() + ": line " + std::to_string(lineno) + " is not valid JSON");
    }
    try {
      FieldReader fr(j, jpath.string(), "line " + std::to_string(lineno));
      Frame f = frame_from(fr.at("frame"));
      if (f.index < static_cast<int>(s.frames.size())) continue;  // already in session.json
      if (f.index != static_cast<int>(s.frames.size()))
        fr.error("frame.index", "expected " + std::to_string(s.frames.size()) + ", got " +
                                    std::to_string(f.index) + " (gap in the journal)");
      check_file_field(s, fr, "color", f.color, opts.check_images, s.color_intrinsics(f));
      check_file_field(s, fr, "depth", f.depth, opts.check_images,
                       s.depth ? std::optional<Intrinsics>(s.depth->intrinsics) : std::nullopt);
      check_file_field(s, fr, "mask", f.mask, opts.check_images, s.color_intrinsics(f));
      s.frames.push_back(std::move(f));
    } catch (const FormatError& e) {
      return fail(e.what());
    }
  }
  return {};
}

}  // namespace

std::optional<Intrinsics> Session::color_intrinsics(const Frame& f) const {
  if (f.intrinsics) return f.intrinsics;
  if (color) return color->intrinsics;
  return std::nullopt;
}

std::string frame_file_name(int index, const char* ext) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%04d.%s", index, ext);
  return buf;
}

Result<Session> load_session(const fs::path& dir, SessionLoadOptions opts) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return fail("'" + dir.string() + "': session folder not found");
  if (auto st = check_links_inside(dir); !st) return std::unexpected(st.error());
  auto j = parse_json_file(dir / "session.json");
  if (!j) return std::unexpected(j.error());
  try {
    Session s = session_from(*j, dir, opts);
    if (auto st = merge_journal(s, opts); !st) return std::unexpected(st.error());
    return s;
  } catch (const FormatError& e) {
    return fail(e.what());
  }
}

Result<ImageU8> load_color(const Session& s, const Frame& f) {
  if (f.color.empty()) return fail("frame " + std::to_string(f.index) + " has no colour image");
  auto p = resolve_inside(s.root, f.color);
  if (!p) return std::unexpected(p.error());
  return read_image_u8(*p);
}

Result<ImageU16> load_depth(const Session& s, const Frame& f) {
  if (f.depth.empty()) return fail("frame " + std::to_string(f.index) + " has no depth image");
  auto p = resolve_inside(s.root, f.depth);
  if (!p) return std::unexpected(p.error());
  auto img = read_image_u16(*p);
  if (img && img->channels != 1)
    return fail("'" + p->string() + "': depth must have 1 channel, has " +
                std::to_string(img->channels));
  return img;
}

Result<ImageU8> load_mask(const Session& s, const Frame& f) {
  if (f.mask.empty()) return fail(ErrorCode::not_found, "frame " + std::to_string(f.index) + " has no matte");
  auto p = resolve_inside(s.root, f.mask);
  if (!p) return std::unexpected(p.error());
  auto img = read_image_u8(*p);
  if (img && img->channels != 1)
    return fail(ErrorCode::format, "'" + p->string() + "': a matte must have 1 channel, has " + std::to_string(img->channels));
  return img;
}

Status save_session_json(const Session& s) {
  return write_file_atomic(s.root / "session.json", dump_json(session_to_json(s)));
}

Result<SessionWriter> SessionWriter::create(Session header) {
  std::error_code ec;
  if (fs::exists(header.root / "session.json", ec))
    return fail("'" + header.root.string() +
                "' already holds a session; resume it to continue, or choose another folder");
  header.frames.clear();
  fs::create_directories(header.root, ec);
  if (ec) return fail("cannot create '" + header.root.string() + "': " + ec.message());
  if (auto st = save_session_json(header); !st) return std::unexpected(st.error());
  return SessionWriter(std::move(header));
}

Result<SessionWriter> SessionWriter::resume(const fs::path& dir) {
  // Temporaries of writes a kill interrupted are never part of the session.
  // Links are checked first: nothing outside the folder is deleted or written.
  if (auto st = check_links_inside(dir); !st) return std::unexpected(with_context(st.error(), "cannot resume"));
  std::error_code ec;
  for (const char* sub : {"", "color", "depth", "points", "mask"})
    for (const auto& e : fs::directory_iterator(dir / sub, ec))
      if (e.path().filename().string().find(".tmp-") != std::string::npos) fs::remove(e.path(), ec);
  auto s = load_session(dir);
  if (!s) return std::unexpected(with_context(s.error(), "cannot resume"));
  return SessionWriter(std::move(*s));
}

Status SessionWriter::add_frame(Frame frame, const ImageU8* color, const ImageU16* depth, const ImageU8* mask) {
  if (frame.index != next_index())
    return fail("frame index " + std::to_string(frame.index) + " but the session expects " +
                std::to_string(next_index()));
  if (color) {
    frame.color = "color/" + frame_file_name(frame.index, "png");
    if (auto st = write_image(session_.root / frame.color, *color, fast_ ? PngEffort::kFast : PngEffort::kCompact); !st)
      return st;
  }
  if (depth) {
    frame.depth = "depth/" + frame_file_name(frame.index, "png");
    if (auto st = write_image(session_.root / frame.depth, *depth, fast_ ? PngEffort::kFast : PngEffort::kCompact); !st)
      return st;
  }
  if (mask) {
    if (!color || mask->channels != 1 || mask->width != color->width || mask->height != color->height)
      return fail(ErrorCode::invalid, "frame " + std::to_string(frame.index) + ": a matte is one channel the colour image's size");
    frame.mask = "mask/" + frame_file_name(frame.index, "png");
    if (auto st = write_image(session_.root / frame.mask, *mask, fast_ ? PngEffort::kFast : PngEffort::kCompact); !st)
      return st;
  }
  json line = {{"frame", frame_to_json(frame)}};
  if (auto st = append_line_durable(session_.root / "session.journal", line.dump()); !st) return st;
  session_.frames.push_back(std::move(frame));
  return save_session_json(session_);
}

}  // namespace s2r
