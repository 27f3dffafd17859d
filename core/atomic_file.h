// Atomic writes: every file the product writes goes through here.
//
// The bytes go to a temporary file in the destination's folder, are fsync'ed,
// and the temporary is renamed over the destination; then the folder is
// fsync'ed. A reader (or a resumed capture) sees the old file or the new one,
// never a half-written one.
#pragma once

#include <filesystem>
#include <functional>
#include <string_view>

#include "core/result.h"

namespace s2r {

// Write `bytes` to `path` atomically. Creates missing parent folders.
Status write_file_atomic(const std::filesystem::path& path, std::string_view bytes);

// For writers that need a real file name (image libraries choose the format by
// extension): `write_to(tmp)` writes the temporary; it is then fsync'ed and
// renamed to `path`. The temporary keeps `path`'s extension.
Status write_via_temp(const std::filesystem::path& path,
                      const std::function<Status(const std::filesystem::path& tmp)>& write_to);

// Append one line to a journal file and fsync it (the line is durable on return).
Status append_line_durable(const std::filesystem::path& path, std::string_view line);

Result<std::string> read_file(const std::filesystem::path& path);

// Fault injection for tests (disk full, I/O errors): the hook runs before
// every write of this module; a non-zero errno it returns fails the write as
// the kernel would. Pass nullptr to remove it.
void set_write_fault_hook(std::function<int(const std::filesystem::path&)> hook);

// fsync a folder so that a rename inside it is durable.
Status sync_directory(const std::filesystem::path& dir);

// A whole folder written atomically (the exports): `out` must not exist or be
// empty (else an error naming it, "out: ..."); `fill(tmp)` writes into a
// temporary folder beside it, which is renamed into place when `fill`
// succeeds and removed when it fails, so a reader sees all of it or nothing.
Status check_new_folder(const std::filesystem::path& out);
Status write_folder_atomic(const std::filesystem::path& out,
                           const std::function<Status(const std::filesystem::path& tmp)>& fill);

}  // namespace s2r
