// Validated reading of the product's versioned JSON files.
//
// Loaders walk a document with FieldReader; any missing, mistyped or
// non-finite field throws FormatError whose message names the file and the
// field path ("session.json: devices.color.intrinsics.fx: expected a finite
// number, got null"). Loaders catch it at their public edge and return a
// Result, so callers never see an exception.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/result.h"

namespace s2r {

struct FormatError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class FieldReader {
 public:
  FieldReader(const nlohmann::json& j, std::string file, std::string path = {})
      : j_(&j), file_(std::move(file)), path_(std::move(path)) {}

  const nlohmann::json& raw() const { return *j_; }
  const std::string& path() const { return path_; }
  bool has(std::string_view key) const;

  FieldReader at(std::string_view key) const;  // required object member
  FieldReader index(size_t i) const;           // array element
  size_t array_size() const;                   // this must be an array

  double number(std::string_view key) const;  // required, finite
  double number_or(std::string_view key, double fallback) const;
  double positive(std::string_view key) const;  // required, finite, > 0
  int64_t integer(std::string_view key) const;
  int64_t integer_or(std::string_view key, int64_t fallback) const;
  std::string string(std::string_view key) const;
  std::string string_or(std::string_view key, std::string fallback) const;
  bool boolean_or(std::string_view key, bool fallback) const;
  // 4x4 row-major rigid transform (rotation checked orthonormal).
  Eigen::Isometry3d rigid(std::string_view key) const;

  [[noreturn]] void error(std::string_view key, const std::string& message) const;
  [[noreturn]] void error(const std::string& message) const;

 private:
  std::string child_path(std::string_view key) const;
  const nlohmann::json& member(std::string_view key) const;
  const nlohmann::json* j_;
  std::string file_;
  std::string path_;
};

// Parse a JSON file. Errors name the file and the byte where parsing stopped.
Result<nlohmann::json> parse_json_file(const std::filesystem::path& path);

// Check {"format": FORMAT, "version": V} with 1 <= V <= max_version; returns V.
int check_format_header(const FieldReader& doc, std::string_view format, int max_version);

// Intrinsics as {"width", "height", "fx", "fy", "cx", "cy", "dist": [5]}.
nlohmann::json intrinsics_to_json(const Intrinsics& k);
// Validated: sizes > 0, fx/fy > 0, everything finite; "dist" optional (zeros).
Intrinsics intrinsics_from(const FieldReader& r);
// [x, y, z], finite.
Eigen::Vector3d vec3_from(const FieldReader& r, std::string_view key);

// 4x4 row-major array for a rigid transform.
nlohmann::json rigid_to_json(const Eigen::Isometry3d& t);

// Serialise with a stable layout (2-space indent) for atomic writing.
std::string dump_json(const nlohmann::json& j);

}  // namespace s2r
