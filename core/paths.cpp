#include "core/paths.h"

#include <algorithm>
#include <cstdlib>

namespace s2r {
namespace fs = std::filesystem;

Result<fs::path> resolve_inside(const fs::path& root, std::string_view relative) {
  if (relative.empty()) return fail(ErrorCode::invalid, "empty file name");
  fs::path rel(relative);
  if (rel.is_absolute()) return fail(ErrorCode::invalid, "path '" + std::string(relative) + "' is absolute; only paths inside the folder are allowed");
  for (const auto& part : rel)
    if (part == "..")
      return fail(ErrorCode::invalid, "path '" + std::string(relative) + "' escapes the folder ('..')");
  std::error_code ec;
  fs::path base = fs::weakly_canonical(root, ec);
  if (ec) return fail("cannot resolve folder '" + root.string() + "': " + ec.message());
  fs::path full = fs::weakly_canonical(base / rel, ec);
  if (ec) return fail("cannot resolve '" + std::string(relative) + "': " + ec.message());
  auto [b, f] = std::mismatch(base.begin(), base.end(), full.begin(), full.end());
  if (b != base.end())
    return fail(ErrorCode::invalid, "path '" + std::string(relative) + "' resolves outside the folder (symbolic link?)");
  return base / rel;
}

Status check_links_inside(const fs::path& root, size_t max_entries) {
  std::error_code ec;
  const fs::path base = fs::weakly_canonical(root, ec);
  if (ec) return fail("cannot resolve folder '" + root.string() + "': " + ec.message());
  size_t n = 0;
  for (fs::recursive_directory_iterator it(base, fs::directory_options::none, ec), end; !ec && it != end; it.increment(ec)) {
    if (++n > max_entries) return fail("'" + root.string() + "' holds more than " + std::to_string(max_entries) + " entries");
    if (!it->is_symlink(ec)) continue;
    const fs::path rel = it->path().lexically_relative(base);
    if (auto p = resolve_inside(base, rel.string()); !p)
      return fail(ErrorCode::invalid, "'" + (root / rel).string() + "' is a symbolic link to outside the folder ('" +
                  fs::read_symlink(it->path(), ec).string() + "'); only links inside it are allowed");
  }
  if (ec) return fail("cannot list '" + root.string() + "': " + ec.message());
  return {};
}

#ifndef S2R_DEFAULT_DATA_DIR
#define S2R_DEFAULT_DATA_DIR "../shared/data"
#endif
#ifndef S2R_BUILD_SOURCE_DIR
#define S2R_BUILD_SOURCE_DIR ""
#endif
#ifndef S2R_BUILD_BINARY_DIR
#define S2R_BUILD_BINARY_DIR ""
#endif

fs::path data_dir() {
  if (const char* env = std::getenv("S2R_DATA"); env && *env) return env;
  return S2R_DEFAULT_DATA_DIR;
}

const char* build_source_dir() { return S2R_BUILD_SOURCE_DIR; }
const char* build_binary_dir() { return S2R_BUILD_BINARY_DIR; }
const char* build_data_dir() { return S2R_DEFAULT_DATA_DIR; }

}  // namespace s2r
