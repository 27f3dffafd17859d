#include "core/report.h"

#include <cmath>
#include <sstream>

#include "core/atomic_file.h"
#include "core/json_fields.h"

namespace s2r {

namespace {
nlohmann::json number(double v) {
  // JSON has no NaN/Inf: write null so the file stays valid and the gap visible.
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}
nlohmann::json numbers(const std::map<std::string, double>& m) {
  nlohmann::json j = nlohmann::json::object();
  for (const auto& [k, v] : m) j[k] = number(v);
  return j;
}
}  // namespace

std::string Report::to_json() const {
  nlohmann::json j;
  j["stage"] = stage;
  j["seconds"] = number(seconds);
  j["errors"] = numbers(errors);
  j["counts"] = numbers(counts);
  j["skipped"] = numbers(skipped);
  nlohmann::json p = nlohmann::json::object();
  for (const auto& [k, v] : params)
    std::visit([&](const auto& x) {
      if constexpr (std::is_same_v<std::decay_t<decltype(x)>, double>) p[k] = number(x);
      else p[k] = x;
    }, v);
  j["params"] = p;
  j["warnings"] = warnings;
  return dump_json(j);
}

Status Report::write(const std::filesystem::path& path) const {
  return write_file_atomic(path, to_json());
}

std::string Report::brief() const {
  std::ostringstream s;
  s.precision(4);
  s << stage << ": " << seconds << " s";
  auto list = [&](const char* name, const std::map<std::string, double>& m) {
    if (m.empty()) return;
    s << "; " << name << ":";
    for (const auto& [k, v] : m) s << " " << k << "=" << v;
  };
  list("errors", errors);
  list("counts", counts);
  list("skipped", skipped);
  return s.str();
}

}  // namespace s2r
