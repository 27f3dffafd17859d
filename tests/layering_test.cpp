// The layer rule (docs/architecture.md): core <- trace <- capture <-
// calibrate <- reconstruct <- render <- app. A stage's sources include only
// headers of its own layer or layers below it. (The build enforces the same
// for linking: each stage's library links only the ones below.) Two arrows
// inside the rule are forbidden too, outside tests: render into reconstruct's
// jobs (what a frame needs lives in reconstruct/frame_inputs.h), and
// reconstruct, calibrate or render into the synthetic rig (ground truth is
// read through capture/ground_truth.h).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <string>

namespace fs = std::filesystem;

namespace {

struct Include {
  fs::path file;
  int line;
  std::string stage;   // the including file's stage
  std::string target;  // "reconstruct/reconstruct_job.h"
  bool test;           // the including file is a test
};

std::vector<Include> all_includes(const std::set<std::string>& stages) {
  const std::regex inc(R"re(^\s*#\s*include\s*"(([a-z_]+)/[a-z_0-9]+\.h)")re");
  std::vector<Include> out;
  for (const auto& stage : stages) {
    const fs::path dir = fs::path(S2R_SOURCE_DIR) / stage;
    for (const auto& e : fs::recursive_directory_iterator(dir)) {
      const auto ext = e.path().extension();
      if (ext != ".h" && ext != ".cpp") continue;
      const bool test = e.path().stem().string().ends_with("_test");
      std::ifstream in(e.path());
      std::string line;
      int lineno = 0;
      while (std::getline(in, line)) {
        ++lineno;
        std::smatch m;
        if (!std::regex_search(line, m, inc)) continue;
        if (!stages.count(m[2])) continue;
        out.push_back({e.path(), lineno, stage, m[1], test});
      }
    }
  }
  return out;
}

}  // namespace

TEST(Layering, IncludesOnlyGoDownward) {
  const std::map<std::string, int> layer = {{"core", 0},      {"trace", 1},  {"capture", 2}, {"calibrate", 3},
                                            {"reconstruct", 4}, {"render", 5}, {"app", 6}};
  std::set<std::string> stages;
  for (const auto& [s, l] : layer) stages.insert(s);
  int checked = 0;
  for (const Include& i : all_includes(stages)) {
    ++checked;
    const std::string target_stage = i.target.substr(0, i.target.find('/'));
    EXPECT_LE(layer.at(target_stage), layer.at(i.stage))
        << i.file << ":" << i.line << " (" << i.stage << ") includes the later layer " << target_stage;
  }
  EXPECT_GT(checked, 10);
}

TEST(Layering, NoStageReachesIntoJobsOrTheSimulator) {
  const std::set<std::string> jobs = {"reconstruct/reconstruct_job.h", "reconstruct/register_job.h"};
  const std::set<std::string> simulator = {"capture/synth_rig.h", "capture/synth_scenes.h", "capture/grbl_sim.h",
                                           "capture/v4l2_sim.h"};
  int checked = 0;
  for (const Include& i : all_includes({"calibrate", "reconstruct", "render"})) {
    if (i.test) continue;
    ++checked;
    if (i.stage == "render") {
      EXPECT_FALSE(jobs.count(i.target)) << i.file << ":" << i.line << " includes the job header " << i.target;
    }
    EXPECT_FALSE(simulator.count(i.target)) << i.file << ":" << i.line << " includes the simulator's " << i.target;
  }
  EXPECT_GT(checked, 10);
}
