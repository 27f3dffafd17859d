// Every stage returns a Report: what it cost, how wrong it is, what it counted
// and what it skipped. `s2r` writes it as report.json:
//   {"stage", "seconds", "errors": {..}, "counts": {..}, "skipped": {..}, "params": {..}}
#pragma once

#include <chrono>
#include <filesystem>
#include <map>
#include <string>
#include <variant>
#include <vector>

#include "core/result.h"

namespace s2r {

using ParamValue = std::variant<double, std::string, bool>;

struct Report {
  std::string stage;
  double seconds = 0;
  std::map<std::string, double> errors;   // how wrong: rms_px, psnr_db, ...
  std::map<std::string, double> counts;   // how much: frames, rays, facets, ...
  std::map<std::string, double> skipped;  // reason -> count of work left out
  std::map<std::string, ParamValue> params;
  std::vector<std::string> warnings;

  std::string to_json() const;
  Status write(const std::filesystem::path& path) const;  // atomic
  // One line for a terminal: "synth: 12.3 s, errors {...}, skipped {...}".
  std::string brief() const;
};

class Stopwatch {
 public:
  Stopwatch() : start_(std::chrono::steady_clock::now()) {}
  double seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace s2r
