// The layer rule (docs/architecture.md): core <- capture <- calibrate <-
// reconstruct <- render <- app. A stage's sources include only headers of its
// own layer or layers below it. (The build enforces the same for linking: each
// stage's library links only the ones below.)
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <string>

namespace fs = std::filesystem;

TEST(Layering, IncludesOnlyGoDownward) {
  const std::map<std::string, int> layer = {{"core", 0},        {"capture", 1}, {"calibrate", 2},
                                            {"reconstruct", 3}, {"render", 4},  {"app", 5}};
  const std::regex inc(R"re(^\s*#\s*include\s*"([a-z_]+)/)re");
  int checked = 0;
  for (const auto& [stage, level] : layer) {
    const fs::path dir = fs::path(S2R_SOURCE_DIR) / stage;
    for (const auto& e : fs::recursive_directory_iterator(dir)) {
      const auto ext = e.path().extension();
      if (ext != ".h" && ext != ".cpp") continue;
      std::ifstream in(e.path());
      std::string line;
      int lineno = 0;
      while (std::getline(in, line)) {
        ++lineno;
        std::smatch m;
        if (!std::regex_search(line, m, inc)) continue;
        auto it = layer.find(m[1]);
        if (it == layer.end()) continue;
        ++checked;
        EXPECT_LE(it->second, level) << e.path() << ":" << lineno << " (" << stage
                                     << ") includes the later layer " << m[1];
      }
    }
  }
  EXPECT_GT(checked, 10);
}
