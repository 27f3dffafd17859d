// s2r-engine: parses the command line as the front did and runs the chosen
// subcommand (docs/cli.md). The front (`s2r`) execs it once a command is to
// run; it links every stage.
#include <malloc.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "app/cli.h"
#include "app/run.h"
#include "core/progress.h"

namespace s2r::cli {

int finish(const Report& report, const std::filesystem::path& path) {
  std::fprintf(stderr, "%s\n", report.brief().c_str());
  for (const auto& w : report.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
  if (auto st = report.write(path); !st) return error(st.error().message);
  std::fprintf(stderr, "report: %s\n", path.c_str());
  return 0;
}

std::vector<std::string> comma_items(const std::string& s) {
  std::vector<std::string> out;
  std::istringstream in(s);
  std::string item;
  while (std::getline(in, item, ',')) out.push_back(item);
  return out;
}

std::optional<double> positive_metres(const std::string& item) {
  char* end = nullptr;
  const double v = std::strtod(item.c_str(), &end);
  if (end == item.c_str() || *end != '\0' || !(v > 0) || !std::isfinite(v)) return std::nullopt;
  return v;
}

std::string in_flag_terms(const Error& e, const FlagNames& names) {
  for (const auto& [field, flag] : names)
    if (e.message.starts_with(field + ":")) return flag + e.message.substr(field.size());
  return e.message;
}

Result<std::array<float, 3>> parse_background(const std::string& s, const std::string& flag) {
  if (s == "white") return std::array<float, 3>{1, 1, 1};
  if (s == "black") return std::array<float, 3>{0, 0, 0};
  const auto items = comma_items(s);
  std::array<float, 3> rgb{};
  bool ok = items.size() == 3;
  for (size_t c = 0; ok && c < 3; ++c) {
    char* end = nullptr;
    const long v = std::strtol(items[c].c_str(), &end, 10);
    ok = end != items[c].c_str() && *end == '\0' && v >= 0 && v <= 255;
    rgb[c] = float(v) / 255.f;
  }
  if (!ok) return fail(ErrorCode::invalid, flag + ": expected white, black or R,G,B with levels 0-255, got '" + s + "'");
  return rgb;
}

Result<std::vector<int>> frame_list(const std::string& s, const std::string& flag) {
  std::vector<int> out;
  for (const auto& item : comma_items(s)) {
    char* end = nullptr;
    const long v = std::strtol(item.c_str(), &end, 10);
    if (end == item.c_str() || *end != '\0' || v < 0 || v > 1000000) return fail(flag + ": '" + item + "' is not a frame index");
    out.push_back(int(v));
  }
  return out;
}

int error(const std::string& message) {
  std::fprintf(stderr, "s2r: error: %s\n", message.c_str());
  return 1;
}

}  // namespace s2r::cli

int main(int argc, char** argv) {
  using namespace s2r::cli;
  // Images, volumes and the cameras' depth are large buffers allocated and
  // freed many times in one command: kept in the heap rather than mapped
  // afresh each time, their pages are not faulted in and zeroed again (on the
  // rig's reconstruct, a tenth of the run was page faults).
  mallopt(M_MMAP_THRESHOLD, 32 << 20);  // glibc's largest
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
  Chosen chosen;
  bool quiet = false;
  if (auto done = parse_command_line(argc, argv, chosen, quiet)) return *done;
  if (quiet) s2r::set_progress_enabled(false);
  // Keep libcamera's probing quiet unless the user asked for its logs.
  setenv("LIBCAMERA_LOG_LEVELS", "*:ERROR", 0);
  return std::visit(
      [](const auto& args) -> int {
        if constexpr (std::is_same_v<std::decay_t<decltype(args)>, std::monostate>) return 2;
        else return run(*args);
      },
      chosen);
}
