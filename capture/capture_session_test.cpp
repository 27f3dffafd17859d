// Whole capture sessions over the simulated rig (real V4L2 and GRBL driver
// code over simulated device boundaries): completion, resume after faults,
// record and replay.
#include "capture/capture_session.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <set>

#include "capture/capture_devices.h"
#include "core/atomic_file.h"
#include "core/progress.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

class CaptureTest : public ::testing::Test {
 protected:
  void SetUp() override {
    set_progress_enabled(false);
    dir_ = fs::temp_directory_path() /
           ("s2r_capture_" + std::to_string(getpid()) + "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override {
    set_write_fault_hook(nullptr);
    fs::remove_all(dir_);
  }
  DeviceOptions devopts() const {
    DeviceOptions d;
    d.width = 96;
    d.height = 72;
    d.settle = 0ms;
    return d;
  }
  Result<Report> capture(const SimOptions& sim, int steps, bool resume, const fs::path& record = {}) {
    DeviceOptions d = devopts();
    d.record_dir = record;
    auto rig = make_sim_capture(sim, d);
    if (!rig) return std::unexpected(rig.error());
    CaptureOptions o;
    o.out = dir_ / "s";
    o.steps = steps;
    o.resume = resume;
    o.flush_frames = 0;
    return run_capture((*rig)->devices, o);
  }
  void expect_complete(int steps) {
    auto s = load_session(dir_ / "s");
    ASSERT_TRUE(s) << s.error().message;
    ASSERT_EQ(s->frames.size(), size_t(steps));
    std::set<std::string> names;
    for (const auto& f : s->frames) {
      EXPECT_NEAR(f.table_angle_commanded_deg, 360.0 * f.index / steps, 1e-9);
      EXPECT_NEAR(f.table_angle_reported_deg, f.table_angle_commanded_deg, 1e-3);
      EXPECT_TRUE(names.insert(f.color).second);
      ASSERT_TRUE(load_color(*s, f));
      ASSERT_TRUE(load_depth(*s, f));
    }
  }
  fs::path dir_;
};

TEST_F(CaptureTest, CompletesAndRefusesToOverwrite) {
  auto r = capture({}, 6, false);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->counts.at("frames_written"), 6);
  EXPECT_LT(r->errors.at("max_table_angle_error_deg"), 1e-3);
  expect_complete(6);
  r = capture({}, 6, false);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("resume it"), std::string::npos);
  r = capture({}, 6, true);  // complete already: nothing to do, nothing overwritten
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->skipped.at("frames_already_captured"), 6);
}

TEST_F(CaptureTest, CameraVanishingMidSessionThenResume) {
  SimOptions sim;
  sim.color_faults.vanish_at = 3;
  auto r = capture(sim, 6, false);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("frame 3: colour camera"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("disconnected"), std::string::npos) << r.error().message;
  EXPECT_EQ(load_session(dir_ / "s")->frames.size(), 3u);
  r = capture({}, 6, true);
  ASSERT_TRUE(r) << r.error().message;
  expect_complete(6);
}

TEST_F(CaptureTest, SerialSilenceAndAlarmThenResume) {
  SimOptions silent;
  silent.table_faults.silent_after = 3;  // G92, then two moves answered
  auto r = capture(silent, 6, false);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("silent"), std::string::npos) << r.error().message;
  SimOptions alarm;
  alarm.table_faults.alarm_at = 2;  // the resume's first move (G92 is line 0... depends) or a later one
  r = capture(alarm, 6, true);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("alarm"), std::string::npos) << r.error().message;
  r = capture({}, 6, true);
  ASSERT_TRUE(r) << r.error().message;
  expect_complete(6);
}

TEST_F(CaptureTest, DiskFullThenResume) {
  set_write_fault_hook([](const fs::path& p) { return p.filename() == "0004.png" ? ENOSPC : 0; });
  auto r = capture({}, 6, false);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("No space left on device"), std::string::npos) << r.error().message;
  set_write_fault_hook(nullptr);
  auto s = load_session(dir_ / "s");
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(s->frames.size(), 4u);
  r = capture({}, 6, true);
  ASSERT_TRUE(r) << r.error().message;
  expect_complete(6);
}

// The fault-injection matrix (docs/testing.md, "Capture faults"): each fault
// at each stage ends in a clear error naming frame and stage, or is absorbed
// and counted; a resume then completes the session and nothing is lost.
TEST_F(CaptureTest, DepthCameraVanishingThenResume) {
  SimOptions sim;
  sim.depth_faults.vanish_at = 4;
  auto r = capture(sim, 6, false);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("depth camera"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("disconnected"), std::string::npos) << r.error().message;
  r = capture({}, 6, true);
  ASSERT_TRUE(r) << r.error().message;
  expect_complete(6);
}

TEST_F(CaptureTest, CameraIoErrorThenResume) {
  for (bool depth : {false, true}) {
    SimOptions sim;
    (depth ? sim.depth_faults : sim.color_faults).eio_at = 2;
    auto r = capture(sim, 4, false);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find(depth ? "depth camera" : "colour camera"), std::string::npos) << r.error().message;
    r = capture({}, 4, true);
    ASSERT_TRUE(r) << r.error().message;
    expect_complete(4);
    fs::remove_all(dir_);
  }
}

TEST_F(CaptureTest, CorruptedFramesAreSkippedNotStored) {
  for (bool depth : {false, true}) {
    SimOptions sim;
    (depth ? sim.depth_faults : sim.color_faults).corrupt_at = 1;
    auto r = capture(sim, 4, false);
    ASSERT_TRUE(r) << r.error().message;
    expect_complete(4);
    fs::remove_all(dir_);
  }
}

TEST_F(CaptureTest, ClockJumpKeepsEveryFrameAndIsCounted) {
  for (int64_t jump : {int64_t(3600) * 1'000'000'000, int64_t(-3600) * 1'000'000'000}) {
    SimOptions sim;
    sim.color_faults.clock_jump_at = 2;  // the colour camera's clock jumps by an hour
    sim.color_faults.clock_jump_ns = jump;
    auto r = capture(sim, 6, false);
    ASSERT_TRUE(r) << r.error().message;
    expect_complete(6);
    EXPECT_GE(r->counts.at("depth_clock_mismatches"), 3);  // frames 2.. cannot be paired by time
    EXPECT_LE(r->counts.at("depth_clock_mismatches"), 5);
    EXPECT_TRUE(std::isfinite(r->errors.at("mean_depth_color_dt_ms")));
    EXPECT_LT(r->errors.at("mean_depth_color_dt_ms"), 1000.0);  // only the frames one clock explains
    fs::remove_all(dir_);
  }
}

TEST_F(CaptureTest, WriteFaultsOnImagesJournalAndHeaderThenResume) {
  struct Case { const char* file; int err; const char* says; };
  for (const Case c : {Case{"0002.png", EIO, "Input/output error"}, Case{"session.journal", ENOSPC, "No space left"},
                       Case{"session.journal", EIO, "Input/output error"}}) {
    set_write_fault_hook([&](const fs::path& p) { return p.filename() == c.file ? c.err : 0; });
    auto r = capture({}, 4, false);
    ASSERT_FALSE(r) << c.file;
    EXPECT_NE(r.error().message.find(c.says), std::string::npos) << r.error().message;
    set_write_fault_hook(nullptr);
    r = capture({}, 4, true);
    ASSERT_TRUE(r) << c.file << ": " << r.error().message;
    expect_complete(4);
    fs::remove_all(dir_);
  }
  // The header of a new session cannot be written: nothing is created, a plain rerun works.
  set_write_fault_hook([](const fs::path& p) { return p.filename() == "session.json" ? ENOSPC : 0; });
  auto r = capture({}, 4, false);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("No space left"), std::string::npos) << r.error().message;
  set_write_fault_hook(nullptr);
  EXPECT_FALSE(fs::exists(dir_ / "s" / "session.json"));
  r = capture({}, 4, false);
  ASSERT_TRUE(r) << r.error().message;
  expect_complete(4);
}

TEST_F(CaptureTest, InterruptStopsBetweenFramesThenResume) {
  auto rig = make_sim_capture({}, devopts());
  ASSERT_TRUE(rig);
  CaptureOptions o;
  o.out = dir_ / "s";
  o.steps = 4;
  o.flush_frames = 0;
  std::atomic<bool> stop{true};
  auto r = run_capture((*rig)->devices, o, &stop);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("interrupted"), std::string::npos);
  rig->reset();
  r = capture({}, 4, true);
  ASSERT_TRUE(r) << r.error().message;
  expect_complete(4);
}

TEST_F(CaptureTest, RecordThenReplayGivesTheSameFrames) {
  const fs::path rec = dir_ / "recording";
  auto r = capture({}, 4, false, rec);
  ASSERT_TRUE(r) << r.error().message;
  ASSERT_TRUE(fs::exists(rec / "color.v4l2rec"));
  ASSERT_TRUE(fs::exists(rec / "turntable.transcript"));
  auto recorded = load_session(dir_ / "s");
  ASSERT_TRUE(recorded);
  DeviceOptions d = devopts();
  auto rig = make_replay_capture(rec, d);
  ASSERT_TRUE(rig) << rig.error().message;
  CaptureOptions o;
  o.out = dir_ / "replayed";
  o.steps = 4;
  o.flush_frames = 0;
  r = run_capture((*rig)->devices, o);
  ASSERT_TRUE(r) << r.error().message;
  auto replayed = load_session(dir_ / "replayed", {.check_images = false});
  ASSERT_TRUE(replayed);
  ASSERT_EQ(replayed->frames.size(), 4u);
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(load_color(*replayed, replayed->frames[i])->data, load_color(*recorded, recorded->frames[i])->data);
    EXPECT_EQ(load_depth(*replayed, replayed->frames[i])->data, load_depth(*recorded, recorded->frames[i])->data);
  }
}

}  // namespace
}  // namespace s2r
