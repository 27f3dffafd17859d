#include "capture/session.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>
#include <random>

#include "core/atomic_file.h"
#include "core/json_fields.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

class SessionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("s2r_session_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A small valid session: 3 frames of 32x24 colour + depth.
  void make_session(int frames = 3) {
    Session h;
    h.root = dir_;
    h.name = "t";
    Intrinsics k;
    k.width = 32; k.height = 24; k.fx = 30; k.fy = 30; k.cx = 15.5; k.cy = 11.5;
    h.color = ColorSensor{"test", "mem", "RGB8", k, 1000, 1};
    DepthSensor d;
    d.intrinsics = k;
    h.depth = d;
    auto w = SessionWriter::create(h);
    ASSERT_TRUE(w) << w.error().message;
    for (int i = 0; i < frames; ++i) {
      ImageU8 c(32, 24, 3, static_cast<uint8_t>(10 * i));
      ImageU16 z(32, 24, 1, static_cast<uint16_t>(500 + i));
      Frame f;
      f.index = i;
      f.table_angle_commanded_deg = 120.0 * i;
      ASSERT_TRUE(w->add_frame(f, &c, &z));
    }
  }

  nlohmann::json json() { return *parse_json_file(dir_ / "session.json"); }
  void put(const nlohmann::json& j) { ASSERT_TRUE(write_file_atomic(dir_ / "session.json", j.dump())); }
  std::string load_error() {
    auto s = load_session(dir_);
    EXPECT_FALSE(s) << "expected the session to be rejected";
    return s ? std::string() : s.error().message;
  }

  fs::path dir_;
};

TEST_F(SessionTest, RoundTrip) {
  make_session();
  auto s = load_session(dir_);
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 3u);
  EXPECT_DOUBLE_EQ(s->frames[2].table_angle_commanded_deg, 240.0);
  EXPECT_DOUBLE_EQ(s->color->intrinsics.fx, 30.0);
  auto c = load_color(*s, s->frames[1]);
  ASSERT_TRUE(c);
  EXPECT_EQ(c->at(5, 5, 0), 10);
  auto z = load_depth(*s, s->frames[2]);
  ASSERT_TRUE(z);
  EXPECT_EQ(z->at(0, 0), 502);
  // No temporary files are left behind by atomic writes.
  for (const auto& e : fs::recursive_directory_iterator(dir_))
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos) << e.path();
}

TEST_F(SessionTest, TruncatedJsonNamesFileAndByte) {
  make_session();
  auto text = *read_file(dir_ / "session.json");
  ASSERT_TRUE(write_file_atomic(dir_ / "session.json", text.substr(0, text.size() / 2)));
  std::string e = load_error();
  EXPECT_NE(e.find("session.json"), std::string::npos) << e;
  EXPECT_NE(e.find("not valid JSON"), std::string::npos) << e;
}

TEST_F(SessionTest, WrongVersion) {
  make_session();
  auto j = json();
  j["version"] = 99;
  put(j);
  std::string e = load_error();
  EXPECT_NE(e.find("session.json: version: unsupported version 99"), std::string::npos) << e;
}

TEST_F(SessionTest, MissingImage) {
  make_session();
  fs::remove(dir_ / "color" / "0001.png");
  std::string e = load_error();
  EXPECT_NE(e.find("frames[1].color"), std::string::npos) << e;
  EXPECT_NE(e.find("not found"), std::string::npos) << e;
}

TEST_F(SessionTest, NaNIntrinsics) {
  make_session();
  auto j = json();
  j["devices"]["color"]["intrinsics"]["fx"] = std::nan("");  // serialised as null
  put(j);
  std::string e = load_error();
  EXPECT_NE(e.find("devices.color.intrinsics.fx: expected a finite number"), std::string::npos) << e;
  j["devices"]["color"]["intrinsics"]["fx"] = "NaN";
  put(j);
  e = load_error();
  EXPECT_NE(e.find("devices.color.intrinsics.fx"), std::string::npos) << e;
}

TEST_F(SessionTest, FrameIndexGap) {
  make_session();
  auto j = json();
  j["frames"][1]["index"] = 2;
  put(j);
  std::string e = load_error();
  EXPECT_NE(e.find("frames[1].index: expected 1"), std::string::npos) << e;
}

TEST_F(SessionTest, PathEscapingTheSession) {
  make_session();
  auto j = json();
  j["frames"][0]["color"] = "../outside.png";
  put(j);
  std::string e = load_error();
  EXPECT_NE(e.find("frames[0].color"), std::string::npos) << e;
  EXPECT_NE(e.find("escapes"), std::string::npos) << e;
  j["frames"][0]["color"] = "/etc/passwd";
  put(j);
  e = load_error();
  EXPECT_NE(e.find("absolute"), std::string::npos) << e;
  // A symbolic link that leads out of the folder.
  fs::create_symlink("/etc", dir_ / "color" / "link");
  j["frames"][0]["color"] = "color/link/hostname";
  put(j);
  e = load_error();
  EXPECT_NE(e.find("outside"), std::string::npos) << e;
}

TEST_F(SessionTest, TruncatedImageIsAClearErrorNeverSilentGarbage) {
  make_session();
  const fs::path png = dir_ / "color" / "0002.png";
  auto s = load_session(dir_, {.check_images = false});
  ASSERT_TRUE(s);
  const auto original = *load_color(*s, s->frames[2]);
  const auto bytes = *read_file(png);
  int rejected = 0;
  for (size_t keep = 0; keep < bytes.size(); ++keep) {
    ASSERT_TRUE(write_file_atomic(png, bytes.substr(0, keep)));
    auto img = load_color(*s, s->frames[2]);
    if (img) {
      // Only the trailing end marker may be missing: then every pixel is intact.
      EXPECT_EQ(img->data, original.data) << "kept " << keep << " of " << bytes.size();
    } else {
      ++rejected;
      EXPECT_NE(img.error().message.find("0002.png"), std::string::npos) << img.error().message;
    }
  }
  EXPECT_GT(rejected, static_cast<int>(bytes.size()) - 20);
  // And the session loader, which opens image headers, names the frame.
  ASSERT_TRUE(write_file_atomic(png, bytes.substr(0, 20)));
  std::string e = load_error();
  EXPECT_NE(e.find("frames[2].color"), std::string::npos) << e;
}

TEST_F(SessionTest, EveryTruncationAndCorruptionOfSessionJsonIsHandled) {
  make_session();
  const auto text = *read_file(dir_ / "session.json");
  for (size_t n = 0; n < text.size(); ++n) {
    ASSERT_TRUE(write_file_atomic(dir_ / "session.json", text.substr(0, n)));
    auto s = load_session(dir_);
    // A prefix is either rejected with a message naming the file, or (if it
    // happens to be complete JSON) a valid session.
    if (!s) {
      ASSERT_NE(s.error().message.find("session.json"), std::string::npos) << s.error().message;
    }
  }
  std::mt19937 rng(1);
  for (int trial = 0; trial < 2000; ++trial) {
    std::string bad = text;
    const size_t at = rng() % bad.size(), len = 1 + rng() % 8;
    for (size_t k = at; k < std::min(bad.size(), at + len); ++k) bad[k] = static_cast<char>(rng() % 256);
    ASSERT_TRUE(write_file_atomic(dir_ / "session.json", bad));
    auto s = load_session(dir_);
    if (!s) {
      EXPECT_FALSE(s.error().message.empty());
    }
  }
}

TEST_F(SessionTest, JournalCoversAKillBetweenJournalAndHeader) {
  // Frame 3's files and journal line exist, session.json still lists 3 frames.
  make_session(4);
  auto four = json();
  four["frames"].erase(3);
  put(four);
  auto s = load_session(dir_);
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(s->frames.size(), 4u);
  // A torn last journal line (killed mid-append) is ignored.
  std::ofstream(dir_ / "session.journal", std::ios::app) << "{\"frame\": {\"ind";
  s = load_session(dir_);
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(s->frames.size(), 4u);
  // Resume continues after the last complete frame.
  auto w = SessionWriter::resume(dir_);
  ASSERT_TRUE(w) << w.error().message;
  EXPECT_EQ(w->next_index(), 4);
}

TEST_F(SessionTest, CreateRefusesToOverwrite) {
  make_session(1);
  Session h;
  h.root = dir_;
  auto w = SessionWriter::create(h);
  ASSERT_FALSE(w);
  EXPECT_NE(w.error().message.find("already holds a session"), std::string::npos);
}

}  // namespace
}  // namespace s2r
