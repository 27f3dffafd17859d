// The other DIY firmwares behind the Turntable interface, each against its
// simulator on a pseudo-terminal: Horus (the Ciclop's GRBL 0.9 fork) and
// FabScanPi; and a real-table capture with the simulated cameras.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "capture/capture_devices.h"
#include "capture/fabscan_turntable.h"
#include "capture/grbl_sim.h"
#include "capture/grbl_turntable.h"
#include "capture/session.h"
#include "core/progress.h"

namespace s2r {
namespace {
using namespace std::chrono_literals;
namespace fs = std::filesystem;

GrblOptions fast(const std::string& dialect) {
  GrblOptions o;
  o.banner_timeout = 400ms;
  o.reply_timeout = 300ms;
  o.settle = 0ms;
  o.poll_interval = 5ms;
  o.retries = 2;
  o.move_timeout = 5000ms;
  o.dialect = dialect;
  return o;
}

FabScanOptions fast_fabscan() {
  FabScanOptions o;
  o.reply_timeout = 400ms;
  o.settle = 0ms;
  return o;
}

TEST(GrblStatus, ParsesGrbl09ReportsAsHorusSendsThem) {
  auto s = parse_grbl_status("<Idle,MPos:15.000,0.000,0.000,WPos:10.000,0.000,0.000>");
  ASSERT_TRUE(s);
  EXPECT_EQ(s->state, "Idle");
  EXPECT_DOUBLE_EQ(s->position, 10.0);  // the work position
  EXPECT_FALSE(s->machine);
  auto y = parse_grbl_status("<Run,MPos:1.000,2.000,3.000,WPos:4.000,5.000,6.000,Buf:0>", 'Y');
  ASSERT_TRUE(y);
  EXPECT_EQ(y->state, "Run");
  EXPECT_DOUBLE_EQ(y->position, 5.0);
  EXPECT_FALSE(parse_grbl_status("<Idle,MPos:1.000,2.000,3.000>"));  // no work position
  EXPECT_FALSE(parse_grbl_status("<Idle,WPos:abc>"));
  EXPECT_EQ(classify_grbl_reply("Horus 0.1 ['$' for help]").kind, GrblReply::kBanner);
}

TEST(Horus, TurnsTheMotorOnHomesWithG50AndMovesWithG1) {
  GrblFaults f;
  f.horus = true;
  auto sim = GrblSim::start(f);
  ASSERT_TRUE(sim) << sim.error().message;
  auto t = GrblTurntable::open((*sim)->port(), fast("horus"));
  ASSERT_TRUE(t) << t.error().message;
  EXPECT_NE((*t)->describe().find("Horus 0.1"), std::string::npos);
  ASSERT_TRUE((*t)->move_to(30));
  ASSERT_TRUE((*t)->home());  // G50: 30 deg is the new 0
  ASSERT_TRUE((*t)->move_to(90));
  auto p = (*t)->position();
  ASSERT_TRUE(p);
  EXPECT_NEAR(*p, 90, 1e-3);
  EXPECT_NEAR((*sim)->table_angle(), 90, 1e-3);  // the table really turned (the motor is on)
  ASSERT_TRUE((*t)->move_to(-45));
  EXPECT_NEAR((*sim)->table_angle(), -45, 1e-3);
}

TEST(Horus, SpokenToAsPlainGrblTheMotorStaysOffAndTheTableStands) {
  // Why the protocol matters: GRBL's commands work, the board counts the
  // steps, but Horus starts with its motor released and nothing turns.
  GrblFaults f;
  f.horus = true;
  auto sim = GrblSim::start(f);
  ASSERT_TRUE(sim);
  auto t = GrblTurntable::open((*sim)->port(), fast("grbl"));
  ASSERT_TRUE(t) << t.error().message;
  ASSERT_TRUE((*t)->move_to(90));
  EXPECT_NEAR(*(*t)->position(), 90, 1e-3);
  EXPECT_NEAR((*sim)->table_angle(), 0, 1e-3);
}

TEST(FabScan, ReadsItsVersionTurnsTheMotorsOnAndMovesBySteps) {
  auto sim = FabScanSim::start(3200);
  ASSERT_TRUE(sim) << sim.error().message;
  auto t = FabScanTurntable::open((*sim)->port(), fast_fabscan());
  ASSERT_TRUE(t) << t.error().message;
  EXPECT_EQ((*t)->version(), "v.20240101-sim");
  EXPECT_TRUE((*sim)->motors_on());
  ASSERT_TRUE((*t)->move_to(90));
  EXPECT_NEAR((*sim)->position(), 90, 1e-9);
  EXPECT_EQ((*t)->steps(), 800);
  ASSERT_TRUE((*t)->move_to(-45));
  EXPECT_NEAR((*sim)->position(), -45, 1e-9);
  // A declared position moves the count, not the table.
  ASSERT_TRUE((*t)->set_position(10));
  EXPECT_NEAR((*sim)->position(), -45, 1e-9);
  ASSERT_TRUE((*t)->move_to(20));
  EXPECT_NEAR((*sim)->position(), -35, 360.0 / 3200);  // 10 and 20 deg round to whole steps
  // Seven steps of a turn do not divide 3200 steps: absolute targets still end at one turn exactly.
  ASSERT_TRUE((*t)->home());
  const double start = (*sim)->position();
  for (int i = 1; i <= 7; ++i) ASSERT_TRUE((*t)->move_to(360.0 * i / 7));
  EXPECT_NEAR((*sim)->position() - start, 360.0, 1e-9);
  // Unknown commands: the firmware says nothing but its prompt.
  auto r = (*t)->command("M999", 400ms);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_TRUE(r->empty());
}

TEST(FabScan, BadBoardsSilenceAndUnpluggingAreClearErrors) {
  FabScanFaults mute;
  mute.not_fabscan = true;
  auto sim = FabScanSim::start(3200, mute);
  ASSERT_TRUE(sim);
  auto t = FabScanTurntable::open((*sim)->port(), fast_fabscan());
  ASSERT_FALSE(t);
  EXPECT_NE(t.error().message.find("FabScanPi board"), std::string::npos) << t.error().message;

  FabScanFaults quiet;
  quiet.silent_after = 2;  // M200 and M17 answered, then nothing
  auto sim2 = FabScanSim::start(3200, quiet);
  ASSERT_TRUE(sim2);
  auto t2 = FabScanTurntable::open((*sim2)->port(), fast_fabscan());
  ASSERT_TRUE(t2) << t2.error().message;
  auto m = (*t2)->move_to(30);
  ASSERT_FALSE(m);
  EXPECT_TRUE(m.error().is(ErrorCode::timeout));
  EXPECT_NE(m.error().message.find("no prompt"), std::string::npos) << m.error().message;
  EXPECT_NEAR(*(*t2)->position(), 0, 1e-9);  // an unconfirmed move is not counted

  auto sim3 = FabScanSim::start();
  ASSERT_TRUE(sim3);
  auto t3 = FabScanTurntable::open((*sim3)->port(), fast_fabscan());
  ASSERT_TRUE(t3);
  (*sim3)->unplug();
  auto u = (*t3)->move_to(30);
  ASSERT_FALSE(u);
  EXPECT_TRUE(u.error().is(ErrorCode::disconnected) || u.error().is(ErrorCode::timeout)) << u.error().message;

  FabScanOptions bad = fast_fabscan();
  bad.steps_per_turn = 0;
  EXPECT_FALSE(FabScanTurntable::open((*sim)->port(), bad));
  EXPECT_FALSE(open_turntable((*sim)->port(), TurntableChoice{.protocol = "marlin"}));
}

TEST(SimCamera, ARealTableWithTheSimulatedCamerasCapturesAtTheAnglesItReports) {
  set_progress_enabled(false);
  for (const std::string protocol : {"fabscan", "horus"}) {
    auto board = start_sim_board(protocol);
    ASSERT_TRUE(board) << board.error().message;
    SimOptions sim;
    sim.scene = "blob";
    DeviceOptions d;
    d.width = 96;
    d.height = 72;
    d.settle = 0ms;
    auto rig = make_sim_camera_capture(board->port(), protocol, sim, d);
    ASSERT_TRUE(rig) << rig.error().message;
    const fs::path out = fs::temp_directory_path() / ("s2r_simcam_" + protocol + "_" + std::to_string(::getpid()));
    fs::remove_all(out);
    CaptureOptions o;
    o.out = out;
    o.steps = 4;
    o.flush_frames = 0;
    auto r = run_capture((*rig)->devices, o);
    ASSERT_TRUE(r) << r.error().message;
    auto s = load_session(out);
    ASSERT_TRUE(s) << s.error().message;
    ASSERT_EQ(s->frames.size(), 4u);
    EXPECT_NE(s->source.find("sim-camera"), std::string::npos);
    ASSERT_TRUE(s->turntable);
    EXPECT_EQ(s->turntable->driver, protocol);
    for (size_t i = 0; i < 4; ++i) EXPECT_NEAR(s->frames[i].table_angle_reported_deg, 90.0 * double(i), 0.01) << protocol;
    // The scene was drawn where the table stood: the frames differ.
    auto a = load_color(*s, s->frames[0]);
    auto b = load_color(*s, s->frames[1]);
    ASSERT_TRUE(a && b);
    EXPECT_NE(a->data, b->data) << protocol;
    fs::remove_all(out);
  }
}

}  // namespace
}  // namespace s2r
