// s2r: turntable scan -> photoreal model (docs/cli.md). This front parses the
// command line and answers --help and usage errors itself, linking no stage
// library, so it starts at once; a command to run is handed to the engine
// beside it (`s2r-engine`, app/engine.cpp), which replaces this process.
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>

#include "app/cli.h"

int main(int argc, char** argv) {
  using namespace s2r::cli;
  Chosen chosen;
  bool quiet = false;
  if (auto done = parse_command_line(argc, argv, chosen, quiet)) return *done;
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) {
    std::fprintf(stderr, "s2r: error: cannot find this program's folder (/proc/self/exe: %s)\n", ec.message().c_str());
    return 2;
  }
  const std::string engine = (self.parent_path() / "s2r-engine").string();
  execv(engine.c_str(), argv);  // returns only on failure
  std::fprintf(stderr, "s2r: error: cannot run %s: %s (build it: cmake --build build --target s2r)\n", engine.c_str(),
               std::strerror(errno));
  return 2;
}
