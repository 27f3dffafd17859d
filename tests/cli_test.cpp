// The s2r binary as a user runs it: help, the main job's steps, exit codes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

namespace {
namespace fs = std::filesystem;

struct Run {
  int code;
  std::string out;
};

Run s2r(const std::string& args) {
  const std::string cmd = std::string(S2R_BINARY_DIR) + "/app/s2r " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  std::string out;
  std::array<char, 512> buf;
  while (p && fgets(buf.data(), buf.size(), p)) out += buf.data();
  int st = p ? pclose(p) : -1;
  return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, out};
}

TEST(Cli, HelpListsTheDesignSubcommands) {
  auto r = s2r("--help");
  EXPECT_EQ(r.code, 0);
  for (const char* sub : {"synth", "import", "devices", "capture", "calibrate", "register", "reconstruct", "render",
                          "eval", "view", "raytrace", "envmap", "bench", "preview", "inspect"})
    EXPECT_NE(r.out.find(sub), std::string::npos) << sub << "\n" << r.out;
}

TEST(Cli, LaterStagesSayNotYetAvailable) {
  auto r = s2r("raytrace scene.json --out x.png");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.out.find("not yet available"), std::string::npos) << r.out;
}

TEST(Cli, SynthInspectPreviewWithReports) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_cli_" + std::to_string(getpid()));
  fs::remove_all(dir);
  auto r = s2r("-q synth --scene blob --views 6 --width 160 --height 120 --out " + (dir / "s").string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(dir / "s" / "report.json"));
  r = s2r("inspect " + (dir / "s").string() + " --decode");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("6 frames"), std::string::npos) << r.out;
  r = s2r("preview " + (dir / "s").string() + " --view 2 --out " + (dir / "p" / "v2.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(dir / "p" / "v2.png"));
  EXPECT_TRUE(fs::exists(dir / "p" / "v2_compare.png"));
  EXPECT_TRUE(fs::exists(dir / "p" / "report.json"));
  // Writing over an existing session is refused, not silently merged.
  r = s2r("synth --scene blob --views 2 --out " + (dir / "s").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("already holds a session"), std::string::npos) << r.out;
  // Bad input: a clear error and exit code 1.
  r = s2r("preview " + (dir / "nope").string() + " --out " + (dir / "x.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("session folder not found"), std::string::npos) << r.out;
  fs::remove_all(dir);
}

}  // namespace
