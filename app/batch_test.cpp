// s2r batch's planning, records and resuming rules (app/batch.h), in process;
// the whole command, killed and resumed, and on a real Slurm: tests/batch_*.
#include "app/batch.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <csignal>
#include <filesystem>
#include <fstream>

#include "calibrate/calibration.h"
#include "capture/synth_rig.h"
#include "core/progress.h"

namespace {
namespace fs = std::filesystem;
using namespace s2r;
using namespace s2r::batch;

struct TempDir {
  fs::path path;
  explicit TempDir(const std::string& name)
      : path(fs::temp_directory_path() / ("s2r_batch_" + name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
};

void touch(const fs::path& p, const std::string& text = "x") {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << text;
}

TEST(Batch, StepsComeInPipelineOrderAndUnknownOnesAreNamed) {
  auto s = parse_steps("eval, import,reconstruct");
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(*s, (std::vector<std::string>{"import", "reconstruct", "eval"}));
  auto bad = parse_steps("import,mesh");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("'mesh'"), std::string::npos);
  EXPECT_NE(bad.error().message.find("calibrate"), std::string::npos);
  EXPECT_FALSE(parse_steps("eval,eval"));
  EXPECT_FALSE(parse_steps(" , "));
}

TEST(Batch, OptionsFileIsValidatedAndKeepsTheBatchsOwnFlags) {
  auto o = parse_options(R"({"holdout": "2,5", "reconstruct": ["--geometry", "hull", "--voxel", 0.01], "heldout_views": 4})",
                         "opts.json");
  ASSERT_TRUE(o) << o.error().message;
  EXPECT_EQ(o->holdout, "2,5");
  EXPECT_EQ(o->heldout_views, 4);
  EXPECT_EQ(o->extra["reconstruct"], (std::vector<std::string>{"--geometry", "hull", "--voxel", "0.01"}));
  for (const char* bad : {R"([1])", R"({"holdout": "x"})", R"({"reconstruct": "--fit 10"})", R"({"colour": 1})",
                          R"({"eval": ["--out", "/tmp/x"]})", R"({"reconstruct": ["--holdout=3"]})", R"({"heldout_views": 0})",
                          R"({"export": "ply"})", "{"}) {
    auto r = parse_options(bad, "opts.json");
    EXPECT_FALSE(r) << bad;
    if (!r) {
      EXPECT_NE(r.error().message.find("opts.json"), std::string::npos) << r.error().message;
    }
  }
}

TEST(Batch, HoldoutAutoLeavesOneFrameInEightAndNeverAll) {
  EXPECT_EQ(*holdout_frames("auto", 24), (std::vector<int>{3, 11, 19}));
  EXPECT_EQ(*holdout_frames("auto", 3), (std::vector<int>{2}));
  EXPECT_TRUE(holdout_frames("auto", 1)->empty());
  EXPECT_TRUE(holdout_frames("none", 10)->empty());
  EXPECT_EQ(*holdout_frames("4,1", 10), (std::vector<int>{4, 1}));
  EXPECT_FALSE(holdout_frames("10", 10));
  EXPECT_FALSE(holdout_frames("-1", 10));
  EXPECT_FALSE(holdout_frames("1,,2", 10));
}

TEST(Batch, DiscoversEachKindOnceAndNotInsideACaptureOrAResultsFolder) {
  TempDir t("discover");
  touch(t.path / "a" / "session.json");
  touch(t.path / "a" / "inner" / "session.json");  // inside a capture: not a capture of its own
  touch(t.path / "lab" / "lego" / "transforms_train.json");
  touch(t.path / "lab" / "proj" / "sparse" / "0" / "cameras.bin");
  touch(t.path / "dino" / "dinoSR_par.txt");
  touch(t.path / "bear" / "color" / "color_0.png");
  touch(t.path / "bear" / "depth" / "depth_0.png");
  touch(t.path / "kitchen" / "frame-000000.color.png");
  touch(t.path / "kitchen" / "frame-000000.pose.txt");
  touch(t.path / "scans" / "bun.conf");  // range scans without colour: not a capture
  touch(t.path / "results" / "batch.json");
  touch(t.path / "results" / "x" / "session" / "session.json");
  touch(t.path / "empty" / "readme.txt");
  auto caps = discover(t.path);
  ASSERT_TRUE(caps) << caps.error().message;
  std::map<std::string, std::string> kinds;
  for (const auto& c : *caps) kinds[c.name] = c.kind;
  EXPECT_EQ(kinds, (std::map<std::string, std::string>{{"a", "session"},
                                                       {"bear", "realsense"},
                                                       {"dino", "middlebury"},
                                                       {"kitchen", "7scenes"},
                                                       {"lab_lego", "nerf"},
                                                       {"lab_proj", "colmap"}}));
  // The root itself as one capture; no capture at all is an error naming what is looked for.
  auto one = discover(t.path / "dino");
  ASSERT_TRUE(one);
  ASSERT_EQ(one->size(), 1u);
  EXPECT_EQ(one->front().kind, "middlebury");
  auto none = discover(t.path / "empty");
  ASSERT_FALSE(none);
  EXPECT_NE(none.error().message.find("session.json"), std::string::npos);
  EXPECT_FALSE(discover(t.path / "missing"));
}

class BatchPlan : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    set_progress_enabled(false);
    dir_ = new TempDir("plan");
    SynthOptions o;
    o.scene = "blob";
    o.views = 6;
    o.width = 96;
    o.height = 72;
    ASSERT_TRUE(synth_session(o, dir_->path / "cap"));
  }
  static void TearDownTestSuite() { delete dir_; }
  static TempDir* dir_;
};
TempDir* BatchPlan::dir_ = nullptr;

TEST_F(BatchPlan, ASessionWithPosesNeedsNoImportNorCalibration) {
  const Capture c{"cap", dir_->path / "cap", "session"};
  const fs::path out = dir_->path / "results" / "cap";
  Options o;
  auto st = capture_state(c, out);
  ASSERT_TRUE(st) << st.error().message;
  EXPECT_EQ(st->frames, 6);
  EXPECT_TRUE(st->has_poses);
  for (const char* step : {"import", "calibrate", "register"}) {
    auto p = plan_step(step, c, out, *st, o);
    ASSERT_TRUE(p) << p.error().message;
    EXPECT_FALSE(p->needed) << step;
    EXPECT_FALSE(p->reason.empty());
  }
  o.extra["reconstruct"] = {"--geometry", "hull"};
  auto rec = plan_step("reconstruct", c, out, *st, o);
  ASSERT_TRUE(rec);
  ASSERT_EQ(rec->commands.size(), 1u);
  const auto& args = rec->commands[0];
  auto at = std::find(args.begin(), args.end(), "--holdout");
  ASSERT_NE(at, args.end());
  EXPECT_EQ(*(at + 1), "3");
  EXPECT_EQ(args.back(), "hull");
  auto ev = plan_step("eval", c, out, *st, o);
  ASSERT_TRUE(ev);
  EXPECT_EQ(ev->outputs, (std::vector<std::string>{"eval"}));
  o.holdout = "none";
  auto no_eval = plan_step("eval", c, out, *st, o);
  ASSERT_TRUE(no_eval);
  EXPECT_FALSE(no_eval->needed);
  // A data set not yet imported: the later steps ask for the import.
  const Capture d{"d", dir_->path / "nowhere", "middlebury"};
  auto st2 = capture_state(d, dir_->path / "results" / "d");
  ASSERT_TRUE(st2);
  auto p2 = plan_step("reconstruct", d, dir_->path / "results" / "d", *st2, o);
  ASSERT_FALSE(p2);
  EXPECT_NE(p2.error().message.find("import"), std::string::npos);
}

TEST_F(BatchPlan, TheTablesMeasuredAnglesGiveThePosesAndRegistrationOnlyChecksThem) {
  const Capture c{"cap", dir_->path / "cap", "session"};
  const fs::path out = dir_->path / "table" / "cap";
  touch(out / "register" / "poses.json", "{}");
  auto sess = load_session(c.path);
  ASSERT_TRUE(sess);
  Calibration cal;
  cal.axis = TurntableAxis{};
  cal.axis->frames_session = sess->name;
  cal.axis->frame_angles_deg.assign(sess->frames.size(), 0.0);
  cal.axis->frame_angles_deg.pop_back();  // another session's count first: not this one's angles
  ASSERT_TRUE(save_calibration(out / "calibrate" / "calibration.json", cal));
  auto uses_poses = [&](const std::string& step) {
    auto st = capture_state(c, out);
    EXPECT_TRUE(st);
    auto p = plan_step(step, c, out, *st, Options{});
    EXPECT_TRUE(p);
    const auto& a = p->commands.at(0);
    EXPECT_NE(std::find(a.begin(), a.end(), "--calibration"), a.end()) << step;
    return std::find(a.begin(), a.end(), "--poses") != a.end();
  };
  EXPECT_FALSE(capture_state(c, out)->table_poses);
  EXPECT_TRUE(uses_poses("reconstruct"));
  EXPECT_TRUE(uses_poses("eval"));
  cal.axis->frame_angles_deg.push_back(0.0);
  ASSERT_TRUE(save_calibration(out / "calibrate" / "calibration.json", cal));
  EXPECT_TRUE(capture_state(c, out)->table_poses);
  for (const char* step : {"reconstruct", "eval", "export"}) EXPECT_FALSE(uses_poses(step)) << step;
  // A calibration that does not parse gives no table poses (the calibrate step redoes it).
  touch(out / "calibrate" / "calibration.json", "{\"trunc");
  EXPECT_TRUE(uses_poses("reconstruct"));
}

TEST_F(BatchPlan, AStepIsSkippedOnlyWithItsRecordItsCommandAndValidOutputs) {
  const Capture c{"cap", dir_->path / "cap", "session"};
  const fs::path out = dir_->path / "skip" / "cap";
  auto st = capture_state(c, out);
  ASSERT_TRUE(st);
  auto p = plan_step("reconstruct", c, out, *st, Options{});
  ASSERT_TRUE(p);
  EXPECT_EQ(why_rerun(out, *p), "not run yet");
  StepRecord r;
  r.step = "reconstruct";
  r.commands = p->commands;
  r.seconds = 1.5;
  r.peak_mb = 321;
  ASSERT_TRUE(write_record(out, r));
  EXPECT_NE(why_rerun(out, *p).find("does not validate"), std::string::npos);  // no model yet
  touch(out / "model" / "model.json", "{}");
  touch(out / "model" / "report.json", R"({"stage": "reconstruct"})");
  EXPECT_EQ(why_rerun(out, *p), "");
  touch(out / "model" / "model.json", "{\"trunc");
  EXPECT_NE(why_rerun(out, *p).find("does not validate"), std::string::npos);
  touch(out / "model" / "model.json", "{}");
  Options other;
  other.extra["reconstruct"] = {"--voxel", "0.01"};
  auto p2 = plan_step("reconstruct", c, out, *st, other);
  ASSERT_TRUE(p2);
  EXPECT_EQ(why_rerun(out, *p2), "its command changed");
  auto back = read_record(out, "reconstruct");
  ASSERT_TRUE(back);
  EXPECT_DOUBLE_EQ(back->peak_mb, 321);
  // The measured peak sets what a Slurm task asks for; unmeasured steps their defaults.
  EXPECT_EQ(task_memory_mb(dir_->path / "skip", {"reconstruct"}), 1024);  // 321 * 1.5 + 512, in 256-MB steps
  EXPECT_GT(task_memory_mb(dir_->path / "skip", {"reconstruct", "register"}), 1024);
}

TEST(Batch, ProcessesReportExitCodesSignalsAndPeakMemory) {
  TempDir t("proc");
  auto ok = run_process("/bin/sh", {"-c", "echo hello; echo oops >&2"}, t.path / "a.log", false);
  ASSERT_TRUE(ok) << ok.error().message;
  EXPECT_EQ(ok->code, 0);
  EXPECT_GT(ok->peak_mb, 0);
  const std::string tail = log_tail(t.path / "a.log", 5);
  EXPECT_NE(tail.find("hello"), std::string::npos);
  EXPECT_NE(tail.find("oops"), std::string::npos);
  EXPECT_NE(tail.find("$ /bin/sh"), std::string::npos);
  auto bad = run_process("/bin/sh", {"-c", "exit 3"}, t.path / "a.log", true);
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->code, 3);
  EXPECT_NE(log_tail(t.path / "a.log", 10).find("hello"), std::string::npos);  // appended
  auto killed = run_process("/bin/sh", {"-c", "kill -9 $$"}, t.path / "b.log", false);
  ASSERT_TRUE(killed);
  EXPECT_EQ(killed->code, 128 + SIGKILL);
  auto missing = run_process("/nonexistent/s2r", {}, t.path / "c.log", false);
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->code, 127);
}

TEST(Batch, ArrayTasksShareTheCapturesOutEvenly) {
  EXPECT_EQ(task_captures(0, 3, 7), (std::vector<int>{0, 3, 6}));
  EXPECT_EQ(task_captures(2, 3, 7), (std::vector<int>{2, 5}));
  EXPECT_TRUE(task_captures(4, 3, 7).empty());
  EXPECT_TRUE(task_captures(0, 0, 7).empty());
}

}  // namespace
