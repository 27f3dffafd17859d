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

// The board homed, then a move to `deg` at `speed` deg/s under fault `f`,
// which must fail: the rig and that move's status.
std::pair<Rig, Status> failing_move(GrblFaults f, double speed, double deg) {
  f.degrees_per_second = speed;
  auto r = connect(f);
  EXPECT_TRUE(r.table->home());
  auto st = r.table->move_to(deg);
  EXPECT_FALSE(st);
  return {std::move(r), st};
}

TEST(GrblStatus, Parses) {
  auto s = parse_grbl_status("<Idle|MPos:15.000,0.000,0.000|FS:0,0>");
  ASSERT_TRUE(s);
  EXPECT_EQ(s->state, "Idle");
  EXPECT_DOUBLE_EQ(s->position, 15.0);
  s = parse_grbl_status("<Run|MPos:-2.5,1,2|FS:500,0>", 'Y');
  ASSERT_TRUE(s);
  EXPECT_DOUBLE_EQ(s->position, 1.0);
  EXPECT_FALSE(parse_grbl_status("ok"));
  EXPECT_FALSE(parse_grbl_status("<Idle|MPos:x,1,2>"));
  // GRBL 1.1: WPos instead of MPos by $10, WCO/Ov/Pn/Bf fields in any order,
  // sub-states, a fourth axis.
  s = parse_grbl_status("<Idle|WPos:1,2,3|Bf:15,128|FS:0,0|WCO:10.5,0,0>");
  ASSERT_TRUE(s);
  EXPECT_DOUBLE_EQ(s->position, 1.0);
  EXPECT_FALSE(s->machine);
  ASSERT_TRUE(s->offset);
  EXPECT_DOUBLE_EQ(*s->offset, 10.5);
  s = parse_grbl_status("<Hold:0|MPos:5,0,0|FS:0,0|Pn:X|Ov:100,100,100>");
  ASSERT_TRUE(s);
  EXPECT_EQ(s->state, "Hold");
  EXPECT_TRUE(s->machine);
  EXPECT_FALSE(s->offset);
  s = parse_grbl_status("<Run|MPos:0,0,0,33.5|FS:0,0>", 'A');
  ASSERT_TRUE(s);
  EXPECT_DOUBLE_EQ(s->position, 33.5);
  EXPECT_FALSE(parse_grbl_status("<Idle|MPos:1,2,3|WPos:1,2,3>"));  // never both
  EXPECT_FALSE(parse_grbl_status("<Idle|FS:0,0>"));
  EXPECT_FALSE(parse_grbl_status("<Idle|MPos:1,2,3|WCO:q,0,0>"));
  EXPECT_FALSE(parse_grbl_status("<Idle|MPos:1|FS:0,0>", 'Y'));  // Y's value is not in the field
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
  // GRBL is deaf after a limit alarm: said as such, not as silence.
  auto p = r.table->position();
  ASSERT_FALSE(p);
  EXPECT_NE(p.error().message.find("halted after alarm 2"), std::string::npos) << p.error().message;
  EXPECT_NE(p.error().message.find("reset"), std::string::npos) << p.error().message;
  EXPECT_TRUE(p.error().is(ErrorCode::device_fault));
}

TEST(GrblTurntable, WorkPositionUnderEveryStatusMask) {
  // $10 bit 0 chooses MPos or WPos, bit 1 adds Bf; G92 moves the work
  // origin, not the motor: the driver reports and commands work positions.
  for (int mask : {0, 1, 2, 3}) {
    SCOPED_TRACE("$10=" + std::to_string(mask));
    GrblFaults f;
    f.status_mask = mask;
    auto r = connect(f);
    ASSERT_TRUE(r.table);
    ASSERT_TRUE(r.table->home());
    ASSERT_TRUE(r.table->move_to(50));
    ASSERT_TRUE(r.table->set_position(0));  // the origin moves to 50 in machine coordinates
    EXPECT_NEAR(r.sim->machine_position(), 50, 1e-3);
    auto p = r.table->position();
    ASSERT_TRUE(p) << p.error().message;
    EXPECT_NEAR(*p, 0, 1e-3);
    for (double a : {10.0, 300.0}) {
      auto st = r.table->move_to(a);
      ASSERT_TRUE(st) << st.error().message;
      EXPECT_NEAR(*r.table->position(), a, 1e-3);
      EXPECT_NEAR(r.sim->position(), a, 1e-3);
      EXPECT_NEAR(r.sim->machine_position(), a + 50, 1e-3);
    }
    // One command line each: no move was sent twice.
    EXPECT_EQ(r.sim->lines_received(), 5);
  }
}

TEST(GrblTurntable, HardLimitHaltsUntilAResetThenAlarmNeedsUnlock) {
  GrblFaults f;
  f.hard_limit_at = 1;
  auto [r, st] = failing_move(f, 180, 90);
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("alarm 1"), std::string::npos) << st.error().message;
  EXPECT_NE(st.error().message.find("hard limit"), std::string::npos) << st.error().message;
  for (int i = 0; i < 2; ++i) {  // every later call: halted, not "silent"
    auto p = r.table->position();
    ASSERT_FALSE(p);
    EXPECT_NE(p.error().message.find("halted after alarm 1"), std::string::npos) << p.error().message;
    EXPECT_EQ(p.error().message.find("silent"), std::string::npos) << p.error().message;
  }
  r.table.reset();
  {  // the board itself ignores '?' and $X while halted
    auto port = SerialPort::open(r.sim->port(), 115200);
    ASSERT_TRUE(port);
    ASSERT_TRUE(port->write("?$X\n"));
    auto line = port->read_line(200ms);
    EXPECT_FALSE(line) << *line;
  }
  // Reopening resets it (Ctrl-X): it comes back in Alarm, G-code is refused
  // with error:9, and $X unlocks it.
  auto t = GrblTurntable::open(r.sim->port(), fast());
  ASSERT_FALSE(t);
  EXPECT_NE(t.error().message.find("alarm state"), std::string::npos) << t.error().message;
  {
    auto port = SerialPort::open(r.sim->port(), 115200);
    ASSERT_TRUE(port);
    ASSERT_TRUE(port->write("G90 G0 X10\n"));
    bool refused = false;
    for (int i = 0; i < 5 && !refused; ++i)
      if (auto l = port->read_line(300ms)) refused = classify_grbl_reply(*l).code == 9;
    EXPECT_TRUE(refused);
  }
  auto o = fast();
  o.unlock_alarm = true;
  t = GrblTurntable::open(r.sim->port(), o);
  ASSERT_TRUE(t) << t.error().message;
  ASSERT_TRUE((*t)->home());
  EXPECT_TRUE((*t)->move_to(20));
  EXPECT_NEAR(r.sim->position(), 20, 1e-3);
}

TEST(GrblTurntable, LateOkIsMatchedToItsOwnCommand) {
  // The first move's "ok" comes after the reply timeout; lines are parsed
  // 20 ms after they arrive while '?' is answered at once, as on the board.
  // The late ok must not be taken as the next move's reply (a status poll
  // would then see the table at the old target and send the move again).
  GrblFaults f;
  f.late_ok_at = 1;
  f.late_ok_ms = 450;
  f.parse_latency_ms = 20;
  auto r = connect(f);
  ASSERT_TRUE(r.table->home());
  for (double a : {45.0, 90.0, 135.0}) {
    auto st = r.table->move_to(a);
    ASSERT_TRUE(st) << st.error().message;
    EXPECT_NEAR(r.sim->position(), a, 1e-3);
  }
  EXPECT_EQ(r.sim->lines_received(), 4);  // G92 and three moves, none twice
}

TEST(GrblSim, AnswersAnEmptyLineAndBootsInAlarmWithHoming) {
  GrblFaults f;
  f.homing_enabled = true;
  auto sim = GrblSim::start(f);
  ASSERT_TRUE(sim);
  auto port = SerialPort::open((*sim)->port(), 115200);
  ASSERT_TRUE(port);
  std::vector<std::string> lines;
  auto read_until = [&](const std::string& want) {
    for (int i = 0; i < 10; ++i) {
      auto l = port->read_line(300ms);
      if (!l) return false;
      lines.push_back(*l);
      if (l->find(want) != std::string::npos) return true;
    }
    return false;
  };
  EXPECT_TRUE(read_until("'$H'|'$X' to unlock"));
  ASSERT_TRUE(port->write("\n"));
  EXPECT_TRUE(read_until("ok"));
  ASSERT_TRUE(port->write("?"));
  EXPECT_TRUE(read_until("<Alarm|MPos:"));
  EXPECT_NE(lines.back().find("WCO:"), std::string::npos) << lines.back();  // first report after a reset
  ASSERT_TRUE(port->write("$H\n"));
  EXPECT_TRUE(read_until("ok"));
  ASSERT_TRUE(port->write("?"));
  EXPECT_TRUE(read_until("<Idle|"));
  EXPECT_NE(lines.back().find("Ov:"), std::string::npos) << lines.back();  // the second report
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
  auto [r, st] = failing_move(f, 90, 90);
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
