#include "capture/colmap_model.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include <fmt/format.h>

#include "core/atomic_file.h"
#include "core/json_fields.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

// The models this importer takes: name, COLMAP's id, parameter count.
struct ColmapModelKind {
  const char* name;
  int id;
  size_t params;
};
constexpr ColmapModelKind kColmapModels[] = {
    {"SIMPLE_PINHOLE", 0, 3}, {"PINHOLE", 1, 4}, {"SIMPLE_RADIAL", 2, 4}, {"RADIAL", 3, 5}, {"OPENCV", 4, 8}};

// Parameters -> intrinsics (f, cx, cy, k... as COLMAP orders them).
Result<ColmapCamera> colmap_camera(const ColmapModelKind& kind, uint64_t width, uint64_t height, const std::vector<double>& p,
                                   const std::string& where) {
  if (p.size() != kind.params)
    return fail(ErrorCode::format, fmt::format("{}: {} has {} parameters, got {}", where, kind.name, kind.params, p.size()));
  for (double x : p)
    if (!std::isfinite(x)) return fail(ErrorCode::format, where + ": a parameter is not finite");
  if (width == 0 || height == 0 || width > 100000 || height > 100000)
    return fail(ErrorCode::format, fmt::format("{}: image size {}x{}", where, width, height));
  ColmapCamera c;
  c.model = kind.name;
  Intrinsics& K = c.K;
  K.width = int(width), K.height = int(height);
  const bool two_focal = kind.id == 1 || kind.id == 4;
  K.fx = p[0];
  K.fy = two_focal ? p[1] : p[0];
  const size_t at = two_focal ? 2 : 1;
  K.cx = p[at] - 0.5, K.cy = p[at + 1] - 0.5;
  if (kind.id == 2) K.dist[0] = p[3];
  if (kind.id == 3) K.dist[0] = p[3], K.dist[1] = p[4];
  if (kind.id == 4) K.dist = {p[4], p[5], p[6], p[7], 0};
  if (auto st = K.validate(where); !st) return std::unexpected(st.error());
  return c;
}

Eigen::Isometry3d cam_from_world(double qw, double qx, double qy, double qz, double tx, double ty, double tz) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::Quaterniond(qw, qx, qy, qz).normalized().toRotationMatrix();
  t.translation() = Eigen::Vector3d(tx, ty, tz);
  return t;
}

bool valid_quaternion(double qw, double qx, double qy, double qz) {
  const double n = std::sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  return std::isfinite(n) && std::abs(n - 1) < 1e-3;
}

// Data lines of a COLMAP text file (comments and blank lines left out), with their line numbers.
Result<std::vector<std::pair<int, std::string>>> colmap_lines(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return fail(ErrorCode::not_found, "'" + path.string() + "': cannot open");
  std::vector<std::pair<int, std::string>> out;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    out.push_back({n, line});
  }
  return out;
}

Result<ColmapModel> read_colmap_text(const fs::path& dir) {
  ColmapModel m;
  m.encoding = "text";
  auto cams = colmap_lines(dir / "cameras.txt");
  if (!cams) return std::unexpected(cams.error());
  for (const auto& [n, line] : *cams) {
    const std::string where = fmt::format("{}: line {}", (dir / "cameras.txt").string(), n);
    std::istringstream ss(line);
    uint32_t id;
    std::string model;
    uint64_t w, h;
    if (!(ss >> id >> model >> w >> h)) return fail(ErrorCode::format, where + ": expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]");
    const ColmapModelKind* kind = nullptr;
    for (const auto& k : kColmapModels)
      if (model == k.name) kind = &k;
    if (!kind)
      return fail(ErrorCode::unsupported,
                  where + ": camera model " + model + " (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)");
    std::vector<double> p;
    for (double x; ss >> x;) p.push_back(x);
    if (!ss.eof()) return fail(ErrorCode::format, where + ": a parameter is not a number");
    auto c = colmap_camera(*kind, w, h, p, where);
    if (!c) return std::unexpected(c.error());
    m.cameras[id] = std::move(*c);
  }
  auto imgs = colmap_lines(dir / "images.txt");
  if (!imgs) return std::unexpected(imgs.error());
  // Two lines an image: its pose, then its 2-D points (which may be empty, and
  // an empty line is then left out by colmap_lines: tell them apart by shape).
  for (size_t i = 0; i < imgs->size(); ++i) {
    const auto& [n, line] = (*imgs)[i];
    const std::string where = fmt::format("{}: line {}", (dir / "images.txt").string(), n);
    std::istringstream ss(line);
    ColmapImage im;
    double q[4], t[3];
    if (!(ss >> im.id >> q[0] >> q[1] >> q[2] >> q[3] >> t[0] >> t[1] >> t[2] >> im.camera >> im.name))
      return fail(ErrorCode::format, where + ": expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME");
    if (!valid_quaternion(q[0], q[1], q[2], q[3]) || !std::isfinite(t[0] + t[1] + t[2]))
      return fail(ErrorCode::format, where + ": the rotation is not a unit quaternion or the translation is not finite");
    im.cam_from_world = cam_from_world(q[0], q[1], q[2], q[3], t[0], t[1], t[2]);
    if (i + 1 < imgs->size() && (*imgs)[i + 1].first == n + 1) {
      std::istringstream pts((*imgs)[++i].second);
      size_t tokens = 0;
      for (std::string tok; pts >> tok;) ++tokens;
      if (tokens % 3) return fail(ErrorCode::format, where + ": the points line needs X Y POINT3D_ID triples");
      im.points2d = tokens / 3;
    }
    m.images.push_back(std::move(im));
  }
  if (fs::exists(dir / "points3D.txt")) {
    auto pts = colmap_lines(dir / "points3D.txt");
    if (!pts) return std::unexpected(pts.error());
    double err = 0;
    for (const auto& [n, line] : *pts) {
      std::istringstream ss(line);
      uint64_t id;
      double x, y, z, e;
      int r, g, b;
      if (!(ss >> id >> x >> y >> z >> r >> g >> b >> e))
        return fail(ErrorCode::format, fmt::format("{}: line {}: expected POINT3D_ID X Y Z R G B ERROR TRACK[]",
                                                   (dir / "points3D.txt").string(), n));
      err += e;
    }
    m.points3d = pts->size();
    m.mean_track_error_px = m.points3d ? err / double(m.points3d) : 0;
  }
  return m;
}

// Little-endian reads of COLMAP's binary files, each bounded by the file's size.
class BinaryReader {
 public:
  explicit BinaryReader(std::string data, std::string name) : d_(std::move(data)), name_(std::move(name)) {}
  template <class T>
  T get() {
    if (d_.size() - at_ < sizeof(T)) throw FormatError(name_ + ": ends early at byte " + std::to_string(at_));
    T v;
    std::memcpy(&v, d_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return v;
  }
  std::string cstring() {
    const size_t end = d_.find('\0', at_);
    if (end == std::string::npos) throw FormatError(name_ + ": a name without its terminating zero");
    std::string s = d_.substr(at_, end - at_);
    at_ = end + 1;
    return s;
  }
  void skip(uint64_t bytes) {
    if (bytes > d_.size() - at_) throw FormatError(name_ + ": ends early at byte " + std::to_string(at_));
    at_ += bytes;
  }
  // A count of records of at least `min_bytes` each that the rest can hold.
  uint64_t count(size_t min_bytes) {
    const uint64_t n = get<uint64_t>();
    if (n > (d_.size() - at_) / std::max<size_t>(1, min_bytes)) throw FormatError(name_ + ": count " + std::to_string(n) + " exceeds the file");
    return n;
  }
  bool done() const { return at_ == d_.size(); }

 private:
  std::string d_, name_;
  size_t at_ = 0;
};

Result<ColmapModel> read_colmap_binary(const fs::path& dir) {
  ColmapModel m;
  m.encoding = "binary";
  try {
    auto text = read_file(dir / "cameras.bin");
    if (!text) return std::unexpected(text.error());
    BinaryReader cams(std::move(*text), (dir / "cameras.bin").string());
    for (uint64_t n = cams.count(24), i = 0; i < n; ++i) {
      const uint32_t id = cams.get<uint32_t>();
      const int32_t model = cams.get<int32_t>();
      const uint64_t w = cams.get<uint64_t>(), h = cams.get<uint64_t>();
      const ColmapModelKind* kind = nullptr;
      for (const auto& k : kColmapModels)
        if (model == k.id) kind = &k;
      const std::string where = fmt::format("{}: camera {}", (dir / "cameras.bin").string(), id);
      if (!kind)
        return fail(ErrorCode::unsupported, fmt::format("{}: camera model id {} (supported: 0-4, SIMPLE_PINHOLE to OPENCV)", where, model));
      std::vector<double> p(kind->params);
      for (double& x : p) x = cams.get<double>();
      auto c = colmap_camera(*kind, w, h, p, where);
      if (!c) return std::unexpected(c.error());
      m.cameras[id] = std::move(*c);
    }
    text = read_file(dir / "images.bin");
    if (!text) return std::unexpected(text.error());
    BinaryReader imgs(std::move(*text), (dir / "images.bin").string());
    for (uint64_t n = imgs.count(64), i = 0; i < n; ++i) {
      ColmapImage im;
      im.id = imgs.get<uint32_t>();
      double q[4], t[3];
      for (double& x : q) x = imgs.get<double>();
      for (double& x : t) x = imgs.get<double>();
      im.camera = imgs.get<uint32_t>();
      im.name = imgs.cstring();
      if (!valid_quaternion(q[0], q[1], q[2], q[3]) || !std::isfinite(t[0] + t[1] + t[2]))
        return fail(ErrorCode::format, fmt::format("{}: image {}: the rotation is not a unit quaternion or the translation is not finite",
                                                   (dir / "images.bin").string(), im.id));
      im.cam_from_world = cam_from_world(q[0], q[1], q[2], q[3], t[0], t[1], t[2]);
      im.points2d = imgs.count(24);
      imgs.skip(im.points2d * 24);
      m.images.push_back(std::move(im));
    }
    if (fs::exists(dir / "points3D.bin")) {
      text = read_file(dir / "points3D.bin");
      if (!text) return std::unexpected(text.error());
      BinaryReader pts(std::move(*text), (dir / "points3D.bin").string());
      double err = 0;
      m.points3d = pts.count(51);
      for (uint64_t i = 0; i < m.points3d; ++i) {
        pts.skip(8 + 24 + 3);
        err += pts.get<double>();
        pts.skip(pts.count(8) * 8);
      }
      m.mean_track_error_px = m.points3d ? err / double(m.points3d) : 0;
    }
  } catch (const FormatError& e) {
    return fail(ErrorCode::format, e.what());
  }
  return m;
}

}  // namespace

Result<ColmapModel> read_colmap_model(const fs::path& dir) {
  const bool binary = fs::exists(dir / "cameras.bin") && fs::exists(dir / "images.bin");
  return binary ? read_colmap_binary(dir) : read_colmap_text(dir);
}

}  // namespace s2r
