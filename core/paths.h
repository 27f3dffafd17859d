// Path safety: files named inside a session or model stay inside its folder.
#pragma once

#include <filesystem>
#include <string_view>

#include "core/result.h"

namespace s2r {

// Resolve `relative` (as written in a session/model file) against `root`.
// Rejects absolute paths, '..' components, empty names, and names that
// resolve (through symbolic links) outside `root`.
Result<std::filesystem::path> resolve_inside(const std::filesystem::path& root,
                                             std::string_view relative);

// Where the real data sets live: $S2R_DATA, else the build-time default.
std::filesystem::path data_dir();

}  // namespace s2r
