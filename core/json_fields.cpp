#include "core/json_fields.h"

#include <cmath>

#include "core/atomic_file.h"

namespace s2r {

namespace {
std::string describe(const nlohmann::json& v) {
  if (v.is_null()) return "null";
  std::string s = v.dump();
  if (s.size() > 40) s = s.substr(0, 37) + "...";
  return s;
}
}  // namespace

std::string FieldReader::child_path(std::string_view key) const {
  return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
}

void FieldReader::error(std::string_view key, const std::string& message) const {
  throw FormatError(file_ + ": " + child_path(key) + ": " + message);
}

void FieldReader::error(const std::string& message) const {
  throw FormatError(file_ + ": " + (path_.empty() ? std::string("(top level)") : path_) + ": " +
                    message);
}

bool FieldReader::has(std::string_view key) const {
  return j_->is_object() && j_->contains(key) && !(*j_)[std::string(key)].is_null();
}

const nlohmann::json& FieldReader::member(std::string_view key) const {
  if (!j_->is_object()) error("expected an object, got " + describe(*j_));
  auto it = j_->find(key);
  if (it == j_->end()) error(key, "missing");
  return *it;
}

FieldReader FieldReader::at(std::string_view key) const {
  return FieldReader(member(key), file_, child_path(key));
}

FieldReader FieldReader::index(size_t i) const {
  if (!j_->is_array()) error("expected an array, got " + describe(*j_));
  if (i >= j_->size()) error("index " + std::to_string(i) + " out of range");
  return FieldReader((*j_)[i], file_, path_ + "[" + std::to_string(i) + "]");
}

size_t FieldReader::array_size() const {
  if (!j_->is_array()) error("expected an array, got " + describe(*j_));
  return j_->size();
}

double FieldReader::number(std::string_view key) const {
  const auto& v = member(key);
  if (!v.is_number()) error(key, "expected a finite number, got " + describe(v));
  double d = v.get<double>();
  if (!std::isfinite(d)) error(key, "expected a finite number, got " + describe(v));
  return d;
}

double FieldReader::number_or(std::string_view key, double fallback) const {
  return has(key) ? number(key) : fallback;
}

double FieldReader::positive(std::string_view key) const {
  double d = number(key);
  if (!(d > 0)) error(key, "must be > 0, got " + std::to_string(d));
  return d;
}

int64_t FieldReader::integer(std::string_view key) const {
  const auto& v = member(key);
  if (!v.is_number_integer()) error(key, "expected an integer, got " + describe(v));
  return v.get<int64_t>();
}

int64_t FieldReader::integer_or(std::string_view key, int64_t fallback) const {
  return has(key) ? integer(key) : fallback;
}

std::string FieldReader::string(std::string_view key) const {
  const auto& v = member(key);
  if (!v.is_string()) error(key, "expected a string, got " + describe(v));
  return v.get<std::string>();
}

std::string FieldReader::string_or(std::string_view key, std::string fallback) const {
  return has(key) ? string(key) : fallback;
}

bool FieldReader::boolean_or(std::string_view key, bool fallback) const {
  if (!has(key)) return fallback;
  const auto& v = member(key);
  if (!v.is_boolean()) error(key, "expected true or false, got " + describe(v));
  return v.get<bool>();
}

Eigen::Isometry3d FieldReader::rigid(std::string_view key) const {
  FieldReader m = at(key);
  if (m.array_size() != 16) m.error("expected 16 numbers (4x4 row-major)");
  Eigen::Matrix4d a;
  for (int i = 0; i < 16; ++i) {
    const auto& v = m.raw()[static_cast<size_t>(i)];
    if (!v.is_number() || !std::isfinite(v.get<double>()))
      m.error("element " + std::to_string(i) + " is not a finite number: " + describe(v));
    a(i / 4, i % 4) = v.get<double>();
  }
  const Eigen::Matrix3d r = a.topLeftCorner<3, 3>();
  if ((r.transpose() * r - Eigen::Matrix3d::Identity()).norm() > 1e-5 || r.determinant() < 0)
    m.error("rotation part is not a proper rotation (R^T R != I or det < 0)");
  if (a.row(3).transpose() != Eigen::Vector4d(0, 0, 0, 1)) m.error("last row must be 0 0 0 1");
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  // Re-orthonormalise the stored rotation so round-trips through text stay rigid.
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(r, Eigen::ComputeFullU | Eigen::ComputeFullV);
  t.linear() = svd.matrixU() * svd.matrixV().transpose();
  t.translation() = a.topRightCorner<3, 1>();
  return t;
}

Result<nlohmann::json> parse_json_file(const std::filesystem::path& path) {
  auto text = read_file(path);
  if (!text) return std::unexpected(text.error());
  if (text->empty()) return fail(ErrorCode::format, path.string() + ": file is empty");
  try {
    return nlohmann::json::parse(*text);
  } catch (const nlohmann::json::parse_error& e) {
    return fail(ErrorCode::format, path.string() + ": not valid JSON (truncated or corrupt?) at byte " +
                std::to_string(e.byte) + ": " + e.what());
  } catch (const nlohmann::json::exception& e) {  // e.g. a number beyond double's range
    return fail(ErrorCode::format, path.string() + ": not valid JSON: " + e.what());
  }
}

int check_format_header(const FieldReader& doc, std::string_view format, int max_version) {
  if (!doc.raw().is_object()) doc.error("expected a JSON object");
  std::string f = doc.string("format");
  if (f != format) doc.error("format", "expected \"" + std::string(format) + "\", got \"" + f + "\"");
  int64_t v = doc.integer("version");
  if (v < 1 || v > max_version)
    doc.error("version", "unsupported version " + std::to_string(v) + " (this build reads 1.." +
                             std::to_string(max_version) + ")");
  return static_cast<int>(v);
}

nlohmann::json intrinsics_to_json(const Intrinsics& k) {
  return {{"width", k.width}, {"height", k.height}, {"fx", k.fx}, {"fy", k.fy},
          {"cx", k.cx},       {"cy", k.cy},         {"dist", k.dist}};
}

Intrinsics intrinsics_from(const FieldReader& r) {
  Intrinsics k;
  k.width = static_cast<int>(r.integer("width"));
  k.height = static_cast<int>(r.integer("height"));
  if (k.width <= 0 || k.height <= 0) r.error("width", "image size must be positive");
  k.fx = r.positive("fx");
  k.fy = r.positive("fy");
  k.cx = r.number("cx");
  k.cy = r.number("cy");
  if (r.has("dist")) {
    FieldReader d = r.at("dist");
    if (d.array_size() != 5) d.error("expected 5 coefficients (k1 k2 p1 p2 k3)");
    for (size_t i = 0; i < 5; ++i) {
      const auto& v = d.raw()[i];
      if (!v.is_number() || !std::isfinite(v.get<double>()))
        d.error("coefficient " + std::to_string(i) + " is not a finite number");
      k.dist[i] = v.get<double>();
    }
  }
  return k;
}

Eigen::Vector3d vec3_from(const FieldReader& r, std::string_view key) {
  FieldReader a = r.at(key);
  if (a.array_size() != 3) a.error("expected 3 numbers");
  Eigen::Vector3d v;
  for (size_t i = 0; i < 3; ++i) {
    const auto& x = a.raw()[i];
    if (!x.is_number() || !std::isfinite(x.get<double>()))
      a.error("element " + std::to_string(i) + " is not a finite number");
    v[static_cast<int>(i)] = x.get<double>();
  }
  return v;
}

nlohmann::json rigid_to_json(const Eigen::Isometry3d& t) {
  nlohmann::json a = nlohmann::json::array();
  const Eigen::Matrix4d m = t.matrix();
  for (int i = 0; i < 16; ++i) a.push_back(m(i / 4, i % 4));
  return a;
}

std::string dump_json(const nlohmann::json& j) { return j.dump(2) + "\n"; }

}  // namespace s2r
