#include <zlib.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <future>

#include <spdlog/fmt/fmt.h>

#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/json_fields.h"
#include "core/paths.h"
#include "reconstruct/model.h"

namespace s2r {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr char kMagic[4] = {'S', '2', 'R', 'B'};
constexpr uint32_t kPayloadVersion = 1;
constexpr size_t kHeader = 24, kFooter = 4;

uint32_t crc(const std::string& bytes, size_t n) {
  return static_cast<uint32_t>(::crc32(0L, reinterpret_cast<const Bytef*>(bytes.data()), static_cast<uInt>(n)));
}

template <class T>
std::string pack(const std::vector<T>& records) {
  static_assert(std::is_trivially_copyable_v<T>);
  std::string b(kHeader + records.size() * sizeof(T) + kFooter, '\0');
  const uint32_t ver = kPayloadVersion, size = sizeof(T);
  const uint64_t count = records.size();
  std::memcpy(b.data(), kMagic, 4);
  std::memcpy(b.data() + 4, &ver, 4);
  std::memcpy(b.data() + 8, &size, 4);
  std::memcpy(b.data() + 16, &count, 8);
  if (!records.empty()) std::memcpy(b.data() + kHeader, records.data(), records.size() * sizeof(T));
  const uint32_t c = crc(b, b.size() - kFooter);
  std::memcpy(b.data() + b.size() - kFooter, &c, 4);
  return b;
}

// A payload's header: its magic, version and record size checked, the
// record count returned.
Result<uint64_t> read_header(std::ifstream& in, const fs::path& path, char (&head)[kHeader], size_t record_size) {
  const std::string name = path.string();
  std::error_code ec;
  const uintmax_t bytes = fs::file_size(path, ec);
  if (ec) return fail(ErrorCode::io, name + ": " + ec.message());
  if (bytes < kHeader + kFooter) return fail(name + ": truncated (" + std::to_string(bytes) + " bytes)");
  if (!in.read(head, kHeader)) return fail(ErrorCode::io, name + ": read error");
  if (std::memcmp(head, kMagic, 4) != 0) return fail(name + ": not an s2r payload (bad magic)");
  uint32_t ver, size;
  uint64_t count;
  std::memcpy(&ver, head + 4, 4);
  std::memcpy(&size, head + 8, 4);
  std::memcpy(&count, head + 16, 8);
  if (ver != kPayloadVersion) return fail(name + ": payload version " + std::to_string(ver) + " unsupported");
  if (record_size && size != record_size)
    return fail(name + ": record size " + std::to_string(size) + ", expected " + std::to_string(record_size));
  if (size == 0 || count > (bytes - kHeader - kFooter) / size || bytes != kHeader + count * size + kFooter)
    return fail(name + ": truncated or padded (" + std::to_string(bytes) + " bytes for " + std::to_string(count) + " records)");
  return count;
}

std::ifstream open_payload(const fs::path& path, Status* st) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    std::error_code ec;
    *st = fs::exists(path, ec) ? fail(ErrorCode::io, "'" + path.string() + "': cannot open for reading")
                               : fail(ErrorCode::not_found, "'" + path.string() + "': file not found");
  }
  return in;
}

// Read straight into the records (one buffer the payload's size: a model of
// hundreds of MB is not copied through a string first), the checksum taken
// over the header and the records as they lie.
template <class T>
Result<std::vector<T>> unpack(const fs::path& path, uint64_t expected_count) {
  static_assert(std::is_trivially_copyable_v<T>);
  const std::string name = path.string();
  Status opened;
  std::ifstream in = open_payload(path, &opened);
  if (!opened) return std::unexpected(opened.error());
  char head[kHeader];
  auto count = read_header(in, path, head, sizeof(T));
  if (!count) return std::unexpected(count.error());
  if (*count != expected_count)
    return fail(name + ": holds " + std::to_string(*count) + " records but model.json says " + std::to_string(expected_count));
  std::vector<T> out(*count);
  uint32_t stored = 0;
  if (!in.read(reinterpret_cast<char*>(out.data()), std::streamsize(*count * sizeof(T))) ||
      !in.read(reinterpret_cast<char*>(&stored), kFooter))
    return fail(ErrorCode::io, name + ": read error");
  uLong c = ::crc32(0L, reinterpret_cast<const Bytef*>(head), kHeader);
  c = ::crc32_z(c, reinterpret_cast<const Bytef*>(out.data()), *count * sizeof(T));
  if (stored != uint32_t(c)) return fail(name + ": checksum mismatch (corrupt)");
  return out;
}

Status check_splats(const fs::path& file, const std::vector<float>& splats, const SplatLayout& layout) {
  const size_t stride = size_t(layout.stride());
  if (splats.size() % stride)
    return fail(file.string() + ": " + std::to_string(splats.size()) + " floats are not whole facets of " + std::to_string(stride));
  for (size_t i = 0; i < splats.size() / stride; ++i) {
    const float* r = &splats[i * stride];
    const std::string at = file.string() + ": facet " + std::to_string(i) + ": ";
    for (size_t k = 0; k < stride; ++k)
      if (!std::isfinite(r[k])) return fail(at + "non-finite value");
    if (!(r[3] > 0)) return fail(at + "sigma must be > 0");
    if (!(r[4] >= 0 && r[4] <= 1)) return fail(at + "opacity outside [0, 1]");
  }
  return {};
}

// The octree payload model.json names, where it names one (FieldReader's
// errors are thrown).
Status read_octree(const FieldReader& doc, const fs::path& dir, Model& m) {
  FieldReader pay = doc.at("payloads");
  if (!pay.has("octree")) return {};
  const uint64_t no = static_cast<uint64_t>(pay.at("octree").integer("records"));
  m.octree_max_level = static_cast<int>(doc.integer("octree_max_level"));
  if (m.octree_max_level < 0 || m.octree_max_level > 30) doc.error("octree_max_level", "must be in 0..30");
  auto oct = unpack<OctreeRecord>(dir / "octree.bin", no);
  if (!oct) return std::unexpected(oct.error());
  m.octree = std::move(*oct);
  return {};
}

// The octree's records against each other and the model's levels.
Status check_octree(const fs::path& dir, const Model& m) {
  const std::string ob = (dir / "octree.bin").string();
  for (size_t i = 0; i < m.octree.size(); ++i) {
    const auto& n = m.octree[i];
    const auto at = [&] { return ob + ": node " + std::to_string(i) + ": "; };
    for (float v : {n.vertex[0], n.vertex[1], n.vertex[2], n.normal[0], n.normal[1], n.normal[2], n.cone, n.shape_error})
      if (!std::isfinite(v)) return fail(at() + "non-finite value");
    if (n.cone < 0 || n.cone > 3.1416f) return fail(at() + "cone angle outside [0, pi]");
    if (n.shape_error < 0) return fail(at() + "negative shape error");
    if (n.level > m.octree_max_level) return fail(at() + "level beyond octree_max_level");
    if (n.first_child == kNoChild) {
      if (n.children != 0) return fail(at() + "children without first_child");
      continue;
    }
    if (n.children == 0 || n.children > 8 || n.first_child <= i || uint64_t(n.first_child) + n.children > m.octree.size())
      return fail(at() + "child range [" + std::to_string(n.first_child) + ", +" + std::to_string(n.children) + ") invalid");
    for (uint32_t c = n.first_child; c < n.first_child + n.children; ++c)
      if (m.octree[c].level != n.level + 1) return fail(at() + "child " + std::to_string(c) + " is not one level down");
  }
  return {};
}

}  // namespace

Status save_splat_payload(const fs::path& file, const std::vector<float>& splats) {
  return write_file_atomic(file, pack(splats));
}

Result<std::vector<float>> load_splat_payload(const fs::path& file, const SplatLayout& layout) {
  Status opened;
  std::ifstream in = open_payload(file, &opened);
  if (!opened) return std::unexpected(opened.error());
  char head[kHeader];
  auto count = read_header(in, file, head, sizeof(float));
  if (!count) return std::unexpected(count.error());
  in.close();
  auto splats = unpack<float>(file, *count);
  if (!splats) return std::unexpected(splats.error());
  if (auto st = check_splats(file, *splats, layout); !st) return std::unexpected(st.error());
  return splats;
}

Status save_model(const fs::path& dir, const Model& m) {
  json cams = json::array();
  for (const auto& c : m.cameras)
    cams.push_back({{"intrinsics", intrinsics_to_json(c.intrinsics)}, {"world_from_camera", rigid_to_json(c.world_from_camera)},
                    {"texture", c.texture}, {"session_frame", c.session_frame}});
  json doc = {{"format", "s2r.model"},
              {"version", kModelVersion},
              {"voxel_size_m", m.voxel_size_m},
              {"bounds", {{"min", {m.bounds.min().x(), m.bounds.min().y(), m.bounds.min().z()}},
                          {"max", {m.bounds.max().x(), m.bounds.max().y(), m.bounds.max().z()}}}},
              {"cameras", cams},
              {"payloads", {{"facets", {{"file", "facets.bin"}, {"records", m.facets.size()}}},
                            {"facet_cameras", {{"file", "facet_cameras.bin"}, {"records", m.facet_cameras.size()}}}}}};
  if (!m.octree.empty()) {
    doc["payloads"]["octree"] = {{"file", "octree.bin"}, {"records", m.octree.size()}};
    doc["octree_max_level"] = m.octree_max_level;
  }
  if (!m.splats.empty()) {
    doc["payloads"]["splats"] = {{"file", "splats.bin"}, {"records", m.splats.size()}};
    doc["splat_sh_degree"] = m.splat_layout.sh_degree;
    doc["splat_pixel_filter_px2"] = m.splat_layout.pixel_filter_px2;
  }
  if (!m.session.empty()) doc["session"] = m.session;
  if (m.patch_mesh) doc["patch_mesh"] = *m.patch_mesh;
  if (m.surface_mesh) doc["surface_mesh"] = *m.surface_mesh;
  if (m.environment) doc["environment"] = *m.environment;
  if (m.backdrop) doc["backdrop"] = *m.backdrop;
  if (m.background) doc["background"] = {(*m.background)[0], (*m.background)[1], (*m.background)[2]};
  // Payloads first, header last: a model.json always describes complete
  // payloads. The payloads are written at once (their flushes to disk
  // overlap); the first failure is reported.
  std::future<Status> facets = std::async(std::launch::async, [&] { return write_file_atomic(dir / "facets.bin", pack(m.facets)); });
  std::future<Status> octree = std::async(std::launch::async, [&]() -> Status {
    return m.octree.empty() ? Status{} : write_file_atomic(dir / "octree.bin", pack(m.octree));
  });
  const Status cameras = write_file_atomic(dir / "facet_cameras.bin", pack(m.facet_cameras));
  const Status splats = m.splats.empty() ? Status{} : write_file_atomic(dir / "splats.bin", pack(m.splats));
  const Status written[] = {facets.get(), cameras, splats, octree.get()};
  for (const Status& st : written)
    if (!st) return st;
  return write_file_atomic(dir / "model.json", dump_json(doc));
}

bool model_has_fit(const fs::path& dir) {
  auto j = parse_json_file(dir / "model.json");
  return j && j->is_object() && j->contains("payloads") && (*j)["payloads"].is_object() && (*j)["payloads"].contains("splats");
}

Result<Model> load_model(const fs::path& dir, ModelLoad what) {
  if (auto st = check_links_inside(dir); !st) return std::unexpected(st.error());
  auto j = parse_json_file(dir / "model.json");
  if (!j) return std::unexpected(j.error());
  Model m;
  try {
    FieldReader doc(*j, (dir / "model.json").string());
    check_format_header(doc, "s2r.model", kModelVersion);
    m.voxel_size_m = doc.positive("voxel_size_m");
    m.session = doc.string_or("session", "");
    FieldReader b = doc.at("bounds");
    for (const char* key : {"min", "max"}) {
      FieldReader v = b.at(key);
      if (v.array_size() != 3) v.error("expected 3 numbers");
      Eigen::Vector3d p;
      for (size_t i = 0; i < 3; ++i) {
        if (!v.raw()[i].is_number() || !std::isfinite(v.raw()[i].get<double>())) v.error("not finite");
        p[static_cast<int>(i)] = v.raw()[i].get<double>();
      }
      (std::string(key) == "min" ? m.bounds.min() : m.bounds.max()) = p;
    }
    FieldReader cams = doc.at("cameras");
    for (size_t i = 0; i < cams.array_size(); ++i) {
      FieldReader c = cams.index(i);
      ModelCamera mc;
      mc.intrinsics = intrinsics_from(c.at("intrinsics"));
      mc.world_from_camera = c.rigid("world_from_camera");
      mc.texture = c.string_or("texture", "");
      mc.session_frame = static_cast<int>(c.integer_or("session_frame", -1));
      if (!mc.texture.empty()) {
        auto p = resolve_inside(dir, mc.texture);
        if (!p) c.error("texture", p.error().message);
        if (!fs::exists(*p)) c.error("texture", "'" + mc.texture + "': file not found");
      }
      m.cameras.push_back(mc);
    }
    if (doc.has("background")) {
      FieldReader b = doc.at("background");
      if (!b.raw().is_array() || b.raw().size() != 3) doc.error("background", "must be [r, g, b]");
      std::array<float, 3> bg{};
      for (size_t i = 0; i < 3; ++i) {
        const auto& v = b.raw()[i];
        if (!v.is_number() || !(v.get<double>() >= 0 && v.get<double>() <= 1)) b.error("each channel must be a number in [0, 1]");
        bg[i] = v.get<float>();
      }
      m.background = bg;
    }
    FieldReader pay = doc.at("payloads");
    const uint64_t nf = static_cast<uint64_t>(pay.at("facets").integer("records"));
    const uint64_t nc = static_cast<uint64_t>(pay.at("facet_cameras").integer("records"));
    for (auto [key, field] : {std::pair{"patch_mesh", &m.patch_mesh}, std::pair{"surface_mesh", &m.surface_mesh},
                              std::pair{"environment", &m.environment}, std::pair{"backdrop", &m.backdrop}}) {
      if (!doc.has(key)) continue;
      *field = doc.string(key);
      if (auto p = resolve_inside(dir, **field); !p) doc.error(key, p.error().message);
    }
    auto facets = unpack<FacetRecord>(dir / "facets.bin", nf);
    if (!facets) return std::unexpected(facets.error());
    auto fc = unpack<uint32_t>(dir / "facet_cameras.bin", nc);
    if (!fc) return std::unexpected(fc.error());
    m.facets = std::move(*facets);
    m.facet_cameras = std::move(*fc);
    if (what.octree)
      if (auto st = read_octree(doc, dir, m); !st) return std::unexpected(st.error());
    if (pay.has("splats")) {
      const uint64_t ns = static_cast<uint64_t>(pay.at("splats").integer("records"));
      m.splat_layout.sh_degree = static_cast<int>(doc.integer("splat_sh_degree"));
      if (m.splat_layout.sh_degree < 0 || m.splat_layout.sh_degree > 2) doc.error("splat_sh_degree", "must be 0, 1 or 2");
      m.splat_layout.pixel_filter_px2 = doc.has("splat_pixel_filter_px2") ? float(doc.number("splat_pixel_filter_px2")) : 0.f;
      if (!(m.splat_layout.pixel_filter_px2 >= 0 && m.splat_layout.pixel_filter_px2 <= 4))
        doc.error("splat_pixel_filter_px2", "must be in [0, 4] (pixels^2)");
      auto sp = unpack<float>(dir / "splats.bin", ns);
      if (!sp) return std::unexpected(sp.error());
      m.splats = std::move(*sp);
    }
  } catch (const FormatError& e) {
    return fail(e.what());
  }
  // Cross-checks between payloads.
  const std::string fb = (dir / "facets.bin").string();
  for (size_t i = 0; i < m.facets.size(); ++i) {
    const auto& f = m.facets[i];
    const auto at = [&] { return fb + ": facet " + std::to_string(i) + ": "; };
    for (float v : {f.center[0], f.center[1], f.center[2], f.size, f.normal[0], f.normal[1], f.normal[2], f.reliability})
      if (!std::isfinite(v)) return fail(at() + "non-finite value");
    if (!(f.size > 0)) return fail(at() + "size must be > 0");
    if (uint64_t(f.first_camera) + f.camera_count > m.facet_cameras.size())
      return fail(at() + "camera range [" + std::to_string(f.first_camera) + ", +" + std::to_string(f.camera_count) +
                  ") exceeds facet_cameras (" + std::to_string(m.facet_cameras.size()) + ")");
  }
  for (size_t i = 0; i < m.facet_cameras.size(); ++i)
    if (m.facet_cameras[i] >= m.cameras.size())
      return fail((dir / "facet_cameras.bin").string() + ": entry " + std::to_string(i) + " names camera " +
                  std::to_string(m.facet_cameras[i]) + " of " + std::to_string(m.cameras.size()));
  if (auto st = check_splats(dir / "splats.bin", m.splats, m.splat_layout); !st) return std::unexpected(st.error());
  if (auto st = check_octree(dir, m); !st) return std::unexpected(st.error());
  return m;
}

Status load_octree(const fs::path& dir, Model& m) {
  if (!m.octree.empty()) return {};
  auto j = parse_json_file(dir / "model.json");
  if (!j) return std::unexpected(j.error());
  Model o;
  try {
    FieldReader doc(*j, (dir / "model.json").string());
    check_format_header(doc, "s2r.model", kModelVersion);
    if (auto st = read_octree(doc, dir, o); !st) return st;
  } catch (const FormatError& e) {
    return fail(e.what());
  }
  if (auto st = check_octree(dir, o); !st) return st;
  m.octree = std::move(o.octree);
  m.octree_max_level = o.octree_max_level;
  return {};
}

Result<std::optional<ImageU8>> load_backdrop(const Model& model, const fs::path& dir) {
  if (!model.backdrop) return std::optional<ImageU8>{};
  auto path = resolve_inside(dir, *model.backdrop);
  if (!path) return std::unexpected(with_context(path.error(), "model backdrop"));
  auto im = read_image_u8(*path);
  if (!im) return std::unexpected(with_context(im.error(), "model backdrop"));
  if (im->channels < 3) return fail(ErrorCode::invalid, "model backdrop '" + path->string() + "': not an RGB image");
  if (!model.cameras.empty() &&
      (im->width != model.cameras[0].intrinsics.width || im->height != model.cameras[0].intrinsics.height))
    return fail(ErrorCode::invalid, fmt::format("model backdrop '{}': {}x{}, the cameras {}x{}", path->string(), im->width,
                                                im->height, model.cameras[0].intrinsics.width, model.cameras[0].intrinsics.height));
  if (im->channels == 3) return std::optional<ImageU8>{std::move(*im)};
  ImageU8 rgb(im->width, im->height, 3);
  for (size_t p = 0; p < rgb.pixels(); ++p)
    for (size_t c = 0; c < 3; ++c) rgb.data[p * 3 + c] = im->data[p * size_t(im->channels) + c];
  return std::optional<ImageU8>{std::move(rgb)};
}

}  // namespace s2r
