// The real termios turntable link against a simulated GRBL firmware on a
// pseudo-terminal, with every injected fault.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <filesystem>

#include "capture/grbl_sim.h"
#include "capture/grbl_turntable.h"
#include "capture/serial_port.h"

namespace s2r {
namespace {
using namespace std::chrono_literals;

GrblOptions fast() {
  GrblOptions o;
  o.banner_timeout = 400ms;
  o.reply_timeout = 300ms;
  o.settle = 0ms;
  o.poll_interval = 5ms;
  o.retries = 2;
  o.move_timeout = 5000ms;
  return o;
}

struct Rig {
  std::unique_ptr<GrblSim> sim;
  std::unique_ptr<GrblTurntable> table;
};

Rig connect(const GrblFaults& f, GrblOptions o = fast()) {
  Rig r;
  auto sim = GrblSim::start(f);
  EXPECT_TRUE(sim) << sim.error().message;
  r.sim = std::move(*sim);
  auto t = GrblTurntable::open(r.sim->port(), o);
  EXPECT_TRUE(t) << t.error().message;
  if (t) r.table = std::move(*t);
  return r;
}

TEST(GrblStatus, Parses) {
  auto s = parse_grbl_status("<Idle|MPos:15.000,0.000,0.000|FS:0,0>");
  ASSERT_TRUE(s);
  EXPECT_EQ(s->state, "Idle");
  EXPECT_DOUBLE_EQ(s->position, 15.0);
  s = parse_grbl_status("<Run|MPos:-2.5,1,2|FS:500,0>", 'Y');
  ASSERT_TRUE(s);
  EXPECT_DOUBLE_EQ(s->position, 1.0);
  EXPECT_FALSE(parse_grbl_status("<Idle|WPos:1,2,3>"));
  EXPECT_FALSE(parse_grbl_status("ok"));
  EXPECT_FALSE(parse_grbl_status("<Idle|MPos:x,1,2>"));
}

TEST(GrblReply, ClassifiesWhatTheBoardSays) {
  EXPECT_EQ(classify_grbl_reply("~#ok").kind, GrblReply::kOk);  // noise glued to the front
  auto r = classify_grbl_reply("error:9");
  EXPECT_EQ(r.kind, GrblReply::kError);
  EXPECT_EQ(r.code, 9);
  r = classify_grbl_reply("ALARM:99999999999999999999");  // no overflow: unreadable
  EXPECT_EQ(r.kind, GrblReply::kAlarm);
  EXPECT_EQ(r.code, -1);
  EXPECT_EQ(classify_grbl_reply("error:").code, -1);
  EXPECT_EQ(classify_grbl_reply("Grbl 1.1h ['$' for help]").kind, GrblReply::kBanner);
  r = classify_grbl_reply("#<Run|MPos:1.5,0,0>");
  EXPECT_EQ(r.kind, GrblReply::kStatus);
  EXPECT_DOUBLE_EQ(r.status.position, 1.5);
  EXPECT_EQ(classify_grbl_reply("[MSG:Caution: Unlocked]").kind, GrblReply::kOther);
}

TEST(LineSplitter, EndingsNoiseChunksAndRunawayLines) {
  LineSplitter lines(8);
  lines.feed("ok\r");
  lines.feed("\nerr\x01or:1\rab");  // "\r\n" split across reads; a control byte dropped
  lines.feed("c\n");
  EXPECT_EQ(lines.next(), "ok");
  EXPECT_EQ(lines.next(), "error:1");
  EXPECT_EQ(lines.next(), "abc");
  EXPECT_FALSE(lines.next());
  lines.feed(std::string(20, 'x'));  // no terminator: cut at 8 bytes, memory bounded
  EXPECT_EQ(lines.next(), std::string(8, 'x'));
  EXPECT_EQ(lines.next(), std::string(8, 'x'));
  EXPECT_FALSE(lines.next());
  EXPECT_EQ(lines.cut_lines(), 2u);
}

TEST(GrblTurntable, HomesMovesAndReportsPosition) {
  auto r = connect({});
  ASSERT_TRUE(r.table);
  ASSERT_TRUE(r.table->home());
  for (double a : {15.0, 30.0, 345.0}) {
    auto st = r.table->move_to(a);
    ASSERT_TRUE(st) << st.error().message;
    EXPECT_NEAR(*r.table->position(), a, 1e-3);
    EXPECT_NEAR(r.sim->position(), a, 1e-3);
  }
}

TEST(GrblTurntable, SetPositionDeclaresWithoutMoving) {
  auto r = connect({});
  ASSERT_TRUE(r.table->set_position(120));
  EXPECT_NEAR(*r.table->position(), 120, 1e-3);
  ASSERT_TRUE(r.table->move_to(135));
  EXPECT_NEAR(r.sim->position(), 135, 1e-3);
}

TEST(GrblTurntable, SoftResetWhenNoBanner) {
  GrblFaults f;
  f.no_banner = true;
  auto r = connect(f);
  ASSERT_TRUE(r.table);
  ASSERT_TRUE(r.table->move_to(10));
}

TEST(GrblTurntable, DroppedOkIsRecoveredByTheStatusPoll) {
  GrblFaults f;
  f.drop_ok_at = 1;  // the first move (line 0 is G92 from home)
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  auto st = r.table->move_to(45);
  ASSERT_TRUE(st) << st.error().message;
  EXPECT_NEAR(r.sim->position(), 45, 1e-3);
}

TEST(GrblTurntable, GarbageAndPartialLinesAreSkipped) {
  GrblFaults f;
  f.garbage_every = 1;
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  for (double a : {20.0, 40.0}) ASSERT_TRUE(r.table->move_to(a));
  EXPECT_NEAR(r.sim->position(), 40, 1e-3);
}

TEST(GrblTurntable, ErrorIsMappedToItsMeaning) {
  GrblFaults f;
  f.error_at = 1;
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  auto st = r.table->move_to(15);
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("error:20"), std::string::npos) << st.error().message;
  EXPECT_TRUE(st.error().is(ErrorCode::protocol));
  EXPECT_NE(st.error().message.find("unsupported or invalid"), std::string::npos);
}

TEST(GrblTurntable, AlarmIsAClearError) {
  GrblFaults f;
  f.alarm_at = 2;
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  ASSERT_TRUE(r.table->move_to(15));
  auto st = r.table->move_to(30);
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("alarm 2"), std::string::npos) << st.error().message;
  EXPECT_TRUE(st.error().is(ErrorCode::device_fault));
  EXPECT_NE(st.error().message.find("soft limit"), std::string::npos);
}

TEST(GrblTurntable, StartInAlarmNeedsUnlock) {
  GrblFaults f;
  f.start_in_alarm = true;
  auto sim = GrblSim::start(f);
  ASSERT_TRUE(sim);
  auto t = GrblTurntable::open((*sim)->port(), fast());
  ASSERT_FALSE(t);
  EXPECT_NE(t.error().message.find("alarm state"), std::string::npos) << t.error().message;
  EXPECT_TRUE(t.error().is(ErrorCode::device_fault));
  auto o = fast();
  o.unlock_alarm = true;
  auto sim2 = GrblSim::start(f);
  t = GrblTurntable::open((*sim2)->port(), o);
  ASSERT_TRUE(t) << t.error().message;
  EXPECT_TRUE((*t)->move_to(5));
}

TEST(GrblTurntable, ResetMidMoveIsReported) {
  GrblFaults f;
  f.reset_mid_move_at = 1;
  f.degrees_per_second = 90;
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  auto st = r.table->move_to(90);
  ASSERT_FALSE(st);
  EXPECT_TRUE(st.error().message.find("reset") != std::string::npos ||
              st.error().message.find("alarm 3") != std::string::npos)
      << st.error().message;
}

TEST(GrblTurntable, SilenceIsRetriedThenReported) {
  GrblFaults f;
  f.silent_after = 2;
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  ASSERT_TRUE(r.table->move_to(10));
  auto st = r.table->move_to(20);
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("silent"), std::string::npos) << st.error().message;
  EXPECT_TRUE(st.error().is(ErrorCode::timeout));
}

TEST(GrblTurntable, UnplugIsReportedAsSuch) {
  auto r = connect({});
  ASSERT_TRUE(r.table->home());
  r.sim->unplug();
  auto st = r.table->move_to(10);
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("disconnected"), std::string::npos) << st.error().message;
  EXPECT_TRUE(st.error().is(ErrorCode::disconnected));
  EXPECT_NE(st.error().sys_errno, 0);
}

TEST(GrblTurntable, NoDeviceIsAClearError) {
  auto t = GrblTurntable::open("/dev/ttyUSB-none", fast());
  ASSERT_FALSE(t);
  EXPECT_NE(t.error().message.find("cannot open serial port"), std::string::npos) << t.error().message;
  EXPECT_TRUE(t.error().is(ErrorCode::not_found));
  EXPECT_EQ(t.error().sys_errno, ENOENT);
}

TEST(GrblTurntable, TranscriptRecordsAndReplays) {
  const auto path = std::filesystem::temp_directory_path() / ("s2r_grbl_" + std::to_string(getpid()) + ".transcript");
  std::filesystem::remove(path);
  {
    auto o = fast();
    o.transcript = path;
    auto r = connect({}, o);
    ASSERT_TRUE(r.table->home());
    ASSERT_TRUE(r.table->move_to(15));
    ASSERT_TRUE(r.table->move_to(30));
  }
  auto replay = GrblSim::replay(path);
  ASSERT_TRUE(replay) << replay.error().message;
  auto t = GrblTurntable::open((*replay)->port(), fast());
  ASSERT_TRUE(t) << t.error().message;
  ASSERT_TRUE((*t)->home());
  ASSERT_TRUE((*t)->move_to(15));
  ASSERT_TRUE((*t)->move_to(30));
  EXPECT_NEAR(*(*t)->position(), 30, 1e-3);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace s2r
