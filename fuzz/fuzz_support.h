// Shared by the libFuzzer targets: a scratch folder per process, and inputs
// that stand for several files at once.
//
// The loaders take paths (they validate what is on disk, names included), so a
// target writes its input into a scratch folder and loads from there. A
// multi-file input holds its files one after another, separated by
// kPartSeparator (also in the targets' dictionaries so mutations keep it).
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace s2r::fuzz {

inline constexpr std::string_view kPartSeparator = "\n--s2r-part--\n";

inline std::vector<std::string_view> split_parts(const uint8_t* data, size_t size) {
  std::vector<std::string_view> parts;
  std::string_view rest(reinterpret_cast<const char*>(data), size);
  for (;;) {
    const size_t at = rest.find(kPartSeparator);
    parts.push_back(rest.substr(0, at));
    if (at == std::string_view::npos) break;
    rest.remove_prefix(at + kPartSeparator.size());
  }
  return parts;
}

// A folder under $TMPDIR (or /dev/shm) that lives as long as the process.
class ScratchDir {
 public:
  ScratchDir() {
    std::error_code ec;
    std::filesystem::path base = "/dev/shm";
    if (const char* t = std::getenv("TMPDIR")) base = t;
    if (!std::filesystem::is_directory(base, ec)) base = std::filesystem::temp_directory_path();
    path_ = base / ("s2r-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(path_, ec);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path write(const std::string& name, std::string_view bytes) const {
    const auto p = path_ / name;
    std::ofstream(p, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    return p;
  }
  void remove(const std::string& name) const {
    std::error_code ec;
    std::filesystem::remove(path_ / name, ec);
  }

 private:
  std::filesystem::path path_;
};

// With S2R_FUZZ_VERBOSE set (checking a corpus by hand), a load's error is printed.
template <class R>
void report(const R& result) {
  if (!std::getenv("S2R_FUZZ_VERBOSE")) return;
  if (result)
    std::fprintf(stderr, "loaded\n");
  else
    std::fprintf(stderr, "rejected: %s\n", result.error().message.c_str());
}

inline const ScratchDir& scratch() {
  static const ScratchDir dir;
  return dir;
}

}  // namespace s2r::fuzz
