#include "core/atomic_file.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>

#include "core/paths.h"
#include "core/report.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

class TempDir : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("s2r_core_" + std::to_string(::getpid()) + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

using AtomicFile = TempDir;
using Paths = TempDir;

TEST_F(AtomicFile, ReplacesWholeOrNotAtAll) {
  const fs::path p = dir_ / "sub" / "a.json";
  ASSERT_TRUE(write_file_atomic(p, "first"));
  EXPECT_EQ(*read_file(p), "first");
  ASSERT_TRUE(write_file_atomic(p, "second, longer"));
  EXPECT_EQ(*read_file(p), "second, longer");
  // A writer that fails leaves the old file and no temporary.
  auto st = write_via_temp(p, [](const fs::path& tmp) -> Status {
    EXPECT_TRUE(write_file_atomic(tmp, "partial"));
    return fail("disk full");
  });
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("disk full"), std::string::npos);
  EXPECT_EQ(*read_file(p), "second, longer");
  for (const auto& e : fs::directory_iterator(p.parent_path())) EXPECT_EQ(e.path().filename(), "a.json");
}

TEST_F(AtomicFile, JournalAppends) {
  const fs::path j = dir_ / "j.log";
  ASSERT_TRUE(append_line_durable(j, "one"));
  ASSERT_TRUE(append_line_durable(j, "two"));
  EXPECT_EQ(*read_file(j), "one\ntwo\n");
  auto missing = read_file(dir_ / "nope");
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.error().message.find("not found"), std::string::npos);
}

TEST_F(AtomicFile, ReadOnlyFolderIsAClearError) {
  if (::geteuid() == 0) GTEST_SKIP() << "root ignores folder permissions";
  fs::permissions(dir_, fs::perms::owner_read | fs::perms::owner_exec);
  auto st = write_file_atomic(dir_ / "x", "y");
  fs::permissions(dir_, fs::perms::owner_all);
  ASSERT_FALSE(st);
}

TEST_F(Paths, StayInsideTheFolder) {
  fs::create_directories(dir_ / "color");
  EXPECT_TRUE(resolve_inside(dir_, "color/0001.png"));
  EXPECT_FALSE(resolve_inside(dir_, "./color/../color/0001.png"));  // '..' is refused outright
  EXPECT_FALSE(resolve_inside(dir_, "../x"));
  EXPECT_FALSE(resolve_inside(dir_, "/etc/passwd"));
  EXPECT_FALSE(resolve_inside(dir_, ""));
  fs::create_symlink("/tmp", dir_ / "color" / "out");
  auto r = resolve_inside(dir_, "color/out/file");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("outside"), std::string::npos);
}

TEST(Report, JsonKeepsNonFiniteVisibleAndValid) {
  Report r;
  r.stage = "t";
  r.seconds = 1.5;
  r.errors["rms_px"] = std::nan("");
  r.errors["psnr_db"] = INFINITY;
  r.counts["frames"] = 3;
  r.skipped["no_pose"] = 2;
  r.params["scene"] = std::string("fuzzy");
  const std::string j = r.to_json();
  EXPECT_NE(j.find("\"rms_px\": null"), std::string::npos) << j;
  EXPECT_NE(j.find("\"no_pose\": 2"), std::string::npos) << j;
  EXPECT_NE(r.brief().find("skipped: no_pose=2"), std::string::npos) << r.brief();
}

}  // namespace
}  // namespace s2r
