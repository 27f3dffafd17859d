// The s2r binary as a user runs it: help, the main job's steps, exit codes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/shell.h"

namespace {
namespace fs = std::filesystem;
using s2r::ShellRun;
using s2r::run_shell;

struct Run {
  int code;
  std::string out;
};

Run run_s2r(const std::string& args) {
  const std::string cmd = std::string(S2R_BINARY_DIR) + "/app/s2r " + args + " 2>&1";
  const ShellRun r = run_shell(cmd);
  return {r.code, r.output};
}

TEST(Cli, HelpListsTheDesignSubcommands) {
  auto r = run_s2r("--help");
  EXPECT_EQ(r.code, 0);
  for (const char* sub : {"synth", "import", "devices", "turntable", "capture", "calibrate", "register", "reconstruct", "render",
                          "eval", "view", "raytrace", "envmap", "bench", "preview", "inspect"})
    EXPECT_NE(r.out.find(sub), std::string::npos) << sub << "\n" << r.out;
}

// Usage errors (an unknown flag, a missing argument or subcommand, a value
// out of range) exit 2 with CLI11's message; help exits 0.
TEST(Cli, UsageErrorsExitTwo) {
  for (const char* args : {"render --bogus", "", "nosuch", "reconstruct", "bench views --out /tmp/x --lego-views -3"}) {
    const auto r = run_s2r(args);
    EXPECT_EQ(r.code, 2) << args << "\n" << r.out;
    EXPECT_FALSE(r.out.empty()) << args;
  }
  EXPECT_EQ(run_s2r("render --help").code, 0);
}

// The front answers --help itself and links no stage library: that is what
// makes every command's help start at once (docs/testing.md, start-up).
TEST(Cli, FrontLinksOnlyTheCxxRuntime) {
  const std::string cmd = "LD_TRACE_LOADED_OBJECTS=1 " + std::string(S2R_BINARY_DIR) + "/app/s2r 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::array<char, 512> buf;
  int libraries = 0;
  std::string all;
  while (fgets(buf.data(), buf.size(), p)) {
    const std::string line = buf.data();
    all += line;
    if (line.find("linux-vdso") != std::string::npos) continue;
    if (line.find("san.so") != std::string::npos) continue;  // a sanitizer build's runtime (libasan, libubsan)
    ++libraries;
    for (const char* heavy : {"OpenImageIO", "opencv", "vtk", "pcl", "ceres", "openvdb", "embree", "camera", "glfw"})
      EXPECT_EQ(line.find(heavy), std::string::npos) << heavy << " in the front:\n" << line;
  }
  pclose(p);
  EXPECT_LE(libraries, 6) << all;  // libstdc++, libm, libgcc_s, libc, ld-linux
}

// Every subcommand's help on one page (--help-all), the front's and the
// engine's the same; and each subcommand's own --help from the front.
TEST(Cli, FrontHelpIsTheEngines) {
  const auto front = run_s2r("--help-all");
  const std::string engine_cmd = std::string(S2R_BINARY_DIR) + "/app/s2r-engine --help-all 2>&1";
  FILE* p = popen(engine_cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string engine;
  std::array<char, 512> buf;
  while (fgets(buf.data(), buf.size(), p)) engine += buf.data();
  pclose(p);
  for (size_t at; (at = engine.find("s2r-engine")) != std::string::npos;) engine.replace(at, 10, "s2r");
  EXPECT_EQ(front.code, 0);
  EXPECT_EQ(front.out, engine);
  for (const char* sub : {"synth", "import", "inspect", "devices", "capture", "calibrate", "calibrate intrinsics",
                          "calibrate depth", "calibrate axis", "calibrate markers", "register", "reconstruct", "preview",
                          "render", "eval", "view", "raytrace", "envmap", "bench", "summary"}) {
    const auto r = run_s2r(std::string(sub) + " --help");
    EXPECT_EQ(r.code, 0) << sub;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << sub;
    EXPECT_NE(front.out.find(std::string(sub).substr(std::string(sub).rfind(' ') + 1)), std::string::npos) << sub;
  }
}

// RegisterJob::validate names its fields; the command line says the flags.
TEST(Cli, RegisterOptionsNameTheFlag) {
  auto r = run_s2r("register --stanford missing.conf --table-sigma-deg 0 --out /tmp/s2r_cli_register_none");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--table-sigma-deg: must be > 0 degrees"), std::string::npos) << r.out;
  r = run_s2r("register --stanford missing.conf --threads -2 --out /tmp/s2r_cli_register_none");
  EXPECT_NE(r.out.find("--threads: must be >= 0"), std::string::npos) << r.out;
}

TEST(Cli, SummaryGathersReportsPlotsAndImages) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_cli_summary_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "eval");
  fs::create_directories(dir / "session" / "color");
  std::ofstream(dir / "session" / "session.json") << "{}";
  std::ofstream(dir / "session" / "color" / "0000.png") << "x";  // a session's frames are inputs: left out
  std::ofstream(dir / "eval" / "report.json")
      << R"({"stage": "eval", "seconds": 2.5, "errors": {"psnr_db_billboards": 24.5, "psnr_db_billboards_frame_0003": 24.5},
            "skipped": {"facets_back_facing": 10}, "counts": {}, "params": {}, "warnings": ["w <1>"]})";
  std::ofstream(dir / "eval" / "eval.csv") << "frame,held_out,mask_pixels,psnr_db_billboards,ssim_billboards,"
                                              "coverage_billboards,frame_ms_billboards\n3,1,100,24.5,0.9,1,12.5\n";
  std::ofstream(dir / "broken") << "";
  auto r = run_s2r("summary " + dir.string() + " --title Run");
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream in(dir / "index.html");
  const std::string html((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(html.find("psnr_db_billboards 24.5"), std::string::npos) << html;
  EXPECT_EQ(html.find("_frame_0003"), std::string::npos) << "per-frame copies are left out of the table";
  EXPECT_NE(html.find("w &lt;1&gt;"), std::string::npos) << "warnings are escaped";
  EXPECT_NE(html.find("eval/psnr_vs_frame_time.png"), std::string::npos) << html;
  EXPECT_EQ(html.find("session/color"), std::string::npos) << "session frames are not results";
  EXPECT_TRUE(fs::exists(dir / "eval" / "psnr_vs_frame_time.png"));
  EXPECT_TRUE(fs::exists(dir / "index.md"));
  EXPECT_EQ(run_s2r("summary " + (dir / "missing").string()).code, 1);
  fs::remove_all(dir);
}

TEST(Cli, TurntableTalksToTheSimulatedFirmwareAndNamesBadInput) {
  auto r = run_s2r("turntable --sim --home --move 90 --move 180.5");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("Grbl 1.1h"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("state Idle"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("moved to 90.000 deg"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("moved to 180.500 deg"), std::string::npos) << r.out;
  r = run_s2r("turntable");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("give a serial port or --sim"), std::string::npos) << r.out;
  r = run_s2r("turntable /dev/ttyUSB-none");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("cannot open serial port"), std::string::npos) << r.out;
}

// Every firmware the driver speaks, against its simulator: --status alone,
// and a full turn with the reported angles.
TEST(Cli, TurntableTurnsOnceAroundWithEachProtocol) {
  for (const std::string protocol : {"grbl", "horus", "fabscan"}) {
    auto r = run_s2r("turntable --sim --protocol " + protocol + " --status");
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_EQ(r.out.find("moved"), std::string::npos) << r.out;
    r = run_s2r("turntable --sim --protocol " + protocol + " --home --turn 4");
    ASSERT_EQ(r.code, 0) << protocol << "\n" << r.out;
    EXPECT_NE(r.out.find("step 4/4 at 360.000 deg"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("largest difference between asked and reported: 0.000 deg"), std::string::npos) << r.out;
  }
  EXPECT_NE(run_s2r("turntable --sim --protocol fabscan").out.find("fabscan:"), std::string::npos);
  EXPECT_NE(run_s2r("turntable --sim --protocol horus").out.find("Horus 0.1"), std::string::npos);
  auto r = run_s2r("turntable --sim --protocol marlin");
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("marlin not in"), std::string::npos) << r.out;
  r = run_s2r("capture --sim-camera --out /tmp/never");
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("--turntable"), std::string::npos) << r.out;
}

TEST(Cli, EnvmapBuildsChecksAndNamesBadInput) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_cli_env_" + std::to_string(getpid()));
  fs::remove_all(dir);
  const std::string pano = std::string(S2R_DATA_DIR) + "/hdri/venice_sunset_1k.hdr";
  if (!fs::exists(pano)) GTEST_SKIP() << "real data not found: " << pano;
  auto r = run_s2r("-q envmap " + pano + " --size 16 --check 40 --out " + (dir / "env.exr").string());
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* f : {"env.exr", "env.png", "report.json"}) EXPECT_TRUE(fs::exists(dir / f)) << f;
  std::ifstream report(dir / "report.json");
  const std::string text((std::istreambuf_iterator<char>(report)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("mean_display_error"), std::string::npos) << text;
  EXPECT_NE(text.find("voxels_outside_unit_ball"), std::string::npos) << text;
  r = run_s2r("envmap " + (dir / "missing.hdr").string() + " --out " + (dir / "x.exr").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("not found"), std::string::npos) << r.out;
  r = run_s2r("envmap " + pano + " --size 1 --out " + (dir / "x.exr").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("2..1024"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir / "x.exr"));
  fs::remove_all(dir);
}

TEST(Cli, SynthInspectPreviewWithReports) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_cli_" + std::to_string(getpid()));
  fs::remove_all(dir);
  auto r = run_s2r("-q synth --scene blob --views 6 --width 160 --height 120 --out " + (dir / "s").string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(dir / "s" / "report.json"));
  r = run_s2r("inspect " + (dir / "s").string() + " --decode");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("6 frames"), std::string::npos) << r.out;
  r = run_s2r("preview " + (dir / "s").string() + " --view 2 --out " + (dir / "p" / "v2.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(dir / "p" / "v2.png"));
  EXPECT_TRUE(fs::exists(dir / "p" / "v2_compare.png"));
  EXPECT_TRUE(fs::exists(dir / "p" / "report.json"));
  // Reconstruct: a model that loads, a report; a bad --voxel is a clear error.
  r = run_s2r("-q reconstruct " + (dir / "s").string() + " --out " + (dir / "m").string());
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* f : {"model.json", "facets.bin", "facet_cameras.bin", "octree.bin", "patches.ply", "report.json",
                        "cameras/0000.exr"})
    EXPECT_TRUE(fs::exists(dir / "m" / f)) << f;
  r = run_s2r("reconstruct " + (dir / "s").string() + " --out " + (dir / "m2").string() + " --voxel -3");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--voxel"), std::string::npos) << r.out;
  r = run_s2r("reconstruct --help");
  EXPECT_NE(r.out.find("--geometry"), std::string::npos) << r.out;
  // Render and eval the model (frame 3 held out), and their clear errors.
  r = run_s2r("-q reconstruct " + (dir / "s").string() + " --out " + (dir / "m3").string() + " --holdout 3");
  ASSERT_EQ(r.code, 0) << r.out;
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --out " + (dir / "r" / "v1.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(dir / "r" / "v1.png"));
  EXPECT_TRUE(fs::exists(dir / "r" / "report.json"));
  r = run_s2r("render " + (dir / "m3").string() + " --view 3 --out " + (dir / "r" / "v3.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--session"), std::string::npos) << r.out;
  r = run_s2r("render " + (dir / "m3").string() + " --view 3 --session " + (dir / "s").string() + " --geometry mesh --out " +
          (dir / "r" / "v3.png").string());
  EXPECT_EQ(r.code, 0) << r.out;
  // The panorama as backdrop: nothing glossy, so no environment map (the
  // report says so); a glossy floor and a sphere build one.
  const std::string pano = std::string(S2R_DATA_DIR) + "/hdri/venice_sunset_1k.hdr";
  if (!fs::exists(pano)) GTEST_SKIP() << "real data not found: " << pano;
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --panorama " + pano + " --out " + (dir / "e1" / "v1.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  {
    std::ifstream f(dir / "e1" / "report.json");
    const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("environment_map_not_needed_no_glossy_material"), std::string::npos) << text;
  }
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --panorama " + pano + " --floor 0.3 --envmap-size 16 --sphere 0,0,0,0.01,0.1 --out " +
          (dir / "e2" / "v1.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  {
    std::ifstream f(dir / "e2" / "report.json");
    const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("\"built\""), std::string::npos) << text;
    EXPECT_NE(text.find("\"envmap_bound\": true"), std::string::npos) << text;
  }
  // A brick relief floor with material LOD: not glossy, so again no map.
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --floor-relief 200,600 --out " + (dir / "e4" / "v1.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  {
    std::ifstream f(dir / "e4" / "report.json");
    const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("environment_map_not_needed_no_glossy_material"), std::string::npos) << text;
  }
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --floor-relief 200,2000 --out " + (dir / "e4" / "v1.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--floor-relief"), std::string::npos) << r.out;
  // Octree LOD with the visual field: the report counts the coarse
  // billboards and what the normal cones culled; a bad gaze is named.
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --lod --lod-texel 8 --lod-shape 4 --lod-luminance 10 --gaze centre "
          "--min-weight 0.1 --out " + (dir / "l" / "v1.png").string());
  ASSERT_EQ(r.code, 0) << r.out;
  {
    std::ifstream f(dir / "l" / "report.json");
    const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("lod_node_billboards"), std::string::npos) << text;
    EXPECT_NE(text.find("facets_back_facing_by_normal_cone"), std::string::npos) << text;
    EXPECT_NE(text.find("facets_outside_visual_field"), std::string::npos) << text;
  }
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --lod --gaze 10 --out " + (dir / "l" / "v1.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--gaze"), std::string::npos) << r.out;
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --floor 0.3 --out " + (dir / "e3" / "v1.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--panorama"), std::string::npos) << r.out;
  r = run_s2r("render " + (dir / "m3").string() + " --view 1 --sphere 1,2,3 --out " + (dir / "e3" / "v1.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--sphere"), std::string::npos) << r.out;
  r = run_s2r("eval " + (dir / "m3").string() + " --session " + (dir / "s").string() + " --holdout 3,1 --out " + (dir / "e").string());
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* f : {"frame_0003.png", "frame_0001.png", "eval.csv", "report.json"}) EXPECT_TRUE(fs::exists(dir / "e" / f)) << f;
  r = run_s2r("eval " + (dir / "m3").string() + " --session " + (dir / "s").string() + " --holdout 3,x");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("not a frame index"), std::string::npos) << r.out;
  // Ray-trace the model's patch mesh (coloured from its cameras) and a PLY;
  // the LOD image equals the full one inside the central field.
  r = run_s2r("raytrace --model " + (dir / "m3").string() + " --size 64 --out " + (dir / "rt").string());
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* f : {"view.png", "full_view.png", "level_view.png", "report.json"}) EXPECT_TRUE(fs::exists(dir / "rt" / f)) << f;
  EXPECT_NE(r.out.find("psnr_central_field_db=100"), std::string::npos) << r.out;
  r = run_s2r("raytrace --mesh " + (dir / "m" / "patches.ply").string() + " --size 48 --full --out " + (dir / "rt2").string());
  ASSERT_EQ(r.code, 0) << r.out;
  r = run_s2r("raytrace --mesh " + (dir / "m" / "patches.ply").string() + " --gaze 0,0,0 --out " + (dir / "rt3").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("gaze"), std::string::npos) << r.out;
  r = run_s2r("raytrace --mesh " + (dir / "m" / "patches.ply").string() + " --eye 1,nan,2 --out " + (dir / "rt3").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--eye"), std::string::npos) << r.out;
  // Writing over an existing session is refused, not silently merged.
  r = run_s2r("synth --scene blob --views 2 --out " + (dir / "s").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("already holds a session"), std::string::npos) << r.out;
  // Bad input: a clear error and exit code 1.
  r = run_s2r("preview " + (dir / "nope").string() + " --out " + (dir / "x.png").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("session folder not found"), std::string::npos) << r.out;
  fs::remove_all(dir);
}

}  // namespace

TEST(Cli, RegisterWritesPosesConfAndPlots) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_cli_reg_" + std::to_string(getpid()));
  fs::remove_all(dir);
  // Usage errors are clear.
  auto r = run_s2r("register --out " + (dir / "x").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--stanford: give either a session or Stanford scans"), std::string::npos) << r.out;
  const std::string conf = std::string(S2R_DATA_DIR) + "/stanford_bunny/bun.conf";
  r = run_s2r("register --stanford " + conf + " --perturb 5 --out " + (dir / "x").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("DEG,M"), std::string::npos) << r.out;
  r = run_s2r("register --stanford " + conf + " --voxels 0.004,-1 --out " + (dir / "x").string());
  EXPECT_EQ(r.code, 1);
  // A synthetic session has no given poses: without a calibration there is no start.
  r = run_s2r("-q synth --scene blob --views 4 --width 160 --height 120 --out " + (dir / "s").string());
  ASSERT_EQ(r.code, 0) << r.out;
  r = run_s2r("-q register " + (dir / "s").string() + " --out " + (dir / "sr").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("calibration"), std::string::npos) << r.out;
  if (!fs::exists(conf)) GTEST_SKIP() << "real data not found";
  // The real scans, coarse levels only (quick): every output is there and the
  // .conf keeps the input's lines.
  r = run_s2r("-q register --stanford " + conf + " --perturb 2,0.002 --voxels 0.004,0.002 --out " + (dir / "b").string());
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* f : {"poses.json", "report.json", "convergence.csv", "views.csv", "pairs.csv", "bun.conf"})
    EXPECT_TRUE(fs::exists(dir / "b" / f)) << f;
  std::ifstream a(conf), b(dir / "b" / "bun.conf");
  std::string la, lb;
  int lines = 0;
  while (std::getline(a, la) && std::getline(b, lb)) {
    ++lines;
    EXPECT_EQ(la.substr(0, la.find(".ply") + 1), lb.substr(0, lb.find(".ply") + 1));
  }
  EXPECT_GE(lines, 11);  // camera + 10 bmesh lines (+ the file's blank line)
  fs::remove_all(dir);
}
