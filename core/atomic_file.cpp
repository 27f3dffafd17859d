#include "core/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>

namespace s2r {
namespace fs = std::filesystem;

namespace {

std::string errno_text(int err) { return std::strerror(err); }

std::function<int(const fs::path&)> g_fault_hook;

Status injected_fault(const fs::path& path) {
  if (!g_fault_hook) return {};
  if (int err = g_fault_hook(path)) return fail(ErrorCode::io, "write to '" + path.string() + "' failed: " + errno_text(err), err);
  return {};
}

fs::path temp_name_for(const fs::path& path) {
  // ".<stem>.tmp-<pid><ext>" keeps the extension for format-by-extension writers.
  return path.parent_path() /
         ("." + path.stem().string() + ".tmp-" + std::to_string(::getpid()) +
          path.extension().string());
}

Status fsync_path(const fs::path& path, int flags) {
  int fd = ::open(path.c_str(), flags | O_CLOEXEC);
  if (fd < 0) return fail(ErrorCode::io, "cannot open '" + path.string() + "' to sync: " + errno_text(errno), errno);
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) return fail(ErrorCode::io, "fsync of '" + path.string() + "' failed: " + errno_text(err), err);
  return {};
}

// write(2) until everything is out, retrying on EINTR.
Status write_all(int fd, std::string_view bytes, const fs::path& path) {
  size_t done = 0;
  while (done < bytes.size()) {
    ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      return fail(ErrorCode::io, "write to '" + path.string() + "' failed: " + errno_text(errno), errno);
    }
    done += static_cast<size_t>(n);
  }
  return {};
}

Status ensure_parent(const fs::path& path) {
  fs::path parent = path.parent_path();
  if (parent.empty()) return {};
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec) return fail("cannot create folder '" + parent.string() + "': " + ec.message());
  return {};
}

}  // namespace

void set_write_fault_hook(std::function<int(const fs::path&)> hook) { g_fault_hook = std::move(hook); }

Status sync_directory(const fs::path& dir) {
  return fsync_path(dir.empty() ? fs::path(".") : dir, O_RDONLY | O_DIRECTORY);
}

Status write_via_temp(const fs::path& path,
                      const std::function<Status(const fs::path& tmp)>& write_to) {
  if (auto st = ensure_parent(path); !st) return st;
  if (auto st = injected_fault(path); !st) return st;
  const fs::path tmp = temp_name_for(path);
  auto cleanup = [&] {
    std::error_code ec;
    fs::remove(tmp, ec);
  };
  if (auto st = write_to(tmp); !st) {
    cleanup();
    return fail_with_context(st.error(), "writing '" + path.string() + "'");
  }
  if (auto st = fsync_path(tmp, O_RDONLY); !st) {
    cleanup();
    return st;
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    int err = errno;
    cleanup();
    return fail(ErrorCode::io, "cannot rename '" + tmp.string() + "' to '" + path.string() + "': " + errno_text(err),
                err);
  }
  return sync_directory(path.parent_path());
}

Status write_file_atomic(const fs::path& path, std::string_view bytes) {
  return write_via_temp(path, [&](const fs::path& tmp) -> Status {
    int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return fail(ErrorCode::io, "cannot create '" + tmp.string() + "': " + errno_text(errno), errno);
    if (auto st = write_all(fd, bytes, tmp); !st) {
      ::close(fd);
      return st;
    }
    if (::close(fd) != 0) return fail(ErrorCode::io, "close of '" + tmp.string() + "' failed: " + errno_text(errno), errno);
    return {};
  });
}

Status append_line_durable(const fs::path& path, std::string_view line) {
  if (auto st = ensure_parent(path); !st) return st;
  if (auto st = injected_fault(path); !st) return st;
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd < 0) return fail(ErrorCode::io, "cannot open journal '" + path.string() + "': " + errno_text(errno), errno);
  std::string buf(line);
  buf.push_back('\n');
  if (auto st = write_all(fd, buf, path); !st) {
    ::close(fd);
    return st;
  }
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) return fail(ErrorCode::io, "fsync of '" + path.string() + "' failed: " + errno_text(err), err);
  return {};
}

Result<std::string> read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    std::error_code ec;
    if (!fs::exists(path, ec)) return fail(ErrorCode::not_found, "'" + path.string() + "': file not found");
    return fail(ErrorCode::io, "'" + path.string() + "': cannot open for reading");
  }
  // A regular file is read in one piece into a string of its size (a
  // stream copied through a stringstream pays for every byte three times);
  // anything else (a pipe, a file still growing) is streamed.
  std::error_code ec;
  const uintmax_t size = fs::is_regular_file(path, ec) ? fs::file_size(path, ec) : 0;
  std::string bytes;
  if (!ec && size > 0) {
    bytes.resize(size);
    if (!in.read(bytes.data(), std::streamsize(size))) return fail(ErrorCode::io, "'" + path.string() + "': read error");
    if (in.peek() == std::char_traits<char>::eof()) return bytes;
    in.clear();
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) return fail(ErrorCode::io, "'" + path.string() + "': read error");
  return bytes + ss.str();
}

Status check_new_folder(const fs::path& out) {
  if (out.empty()) return fail(ErrorCode::invalid, "out: no folder given");
  std::error_code ec;
  if (fs::exists(out, ec) && (!fs::is_directory(out, ec) || !fs::is_empty(out, ec)))
    return fail(ErrorCode::invalid, "out: '" + out.string() + "' exists and is not empty: choose a new folder (nothing was written)");
  return {};
}

Status write_folder_atomic(const fs::path& out_path, const std::function<Status(const fs::path& tmp)>& fill) {
  if (auto st = check_new_folder(out_path); !st) return st;
  const fs::path out = fs::absolute(out_path).lexically_normal();
  const fs::path tmp = out.parent_path() / ("." + out.filename().string() + ".partial-" + std::to_string(getpid()));
  std::error_code ec;
  fs::remove_all(tmp, ec);
  fs::create_directories(tmp, ec);
  if (ec) return fail(ErrorCode::io, "cannot create " + tmp.string() + ": " + ec.message());
  if (auto st = fill(tmp); !st) {
    fs::remove_all(tmp, ec);
    return st;
  }
  if (fs::exists(out, ec)) fs::remove(out, ec);  // an empty folder
  fs::rename(tmp, out, ec);
  if (ec) {
    fs::remove_all(tmp, ec);
    return fail(ErrorCode::io, "cannot move " + tmp.string() + " into " + out.string() + ": " + ec.message());
  }
  return sync_directory(out.parent_path());
}

}  // namespace s2r
