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

// Every symbolic link under `root` (not followed) must resolve inside it: a
// session or model folder cannot send a reader (or a resumed writer) outside
// through a link planted anywhere in it, e.g. ground_truth -> /etc. The
// error names the first link that leaves. `max_entries` bounds the walk.
Status check_links_inside(const std::filesystem::path& root, size_t max_entries = 1'000'000);

// Where the real data sets live: $S2R_DATA, else the build-time default.
std::filesystem::path data_dir();

// Where this build was configured from and into, and its data folder: what
// tests and benches find their inputs by. Only core/paths.cpp is compiled
// with these paths, so that every other translation unit's compile command is
// the same in any checkout (ccache hits across clones). Empty where unknown.
const char* build_source_dir();
const char* build_binary_dir();
const char* build_data_dir();

}  // namespace s2r
