#include "capture/import_datasets.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include "capture/session.h"
#include "core/mesh.h"
#include "core/paths.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

class ImportTest : public ::testing::Test {
 protected:
  void SetUp() override {
    data_ = S2R_DATA_DIR;
    if (!fs::exists(data_)) GTEST_SKIP() << "real data not found at " << data_;
    out_ = fs::temp_directory_path() / ("s2r_import_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(out_);
  }
  void TearDown() override { fs::remove_all(out_); }
  fs::path data_, out_;
};

TEST_F(ImportTest, StanfordScansWithConfPoses) {
  auto r = import_dataset("stanford", data_ / "stanford_bunny" / "bun.conf", out_, {.stride = 1, .max_frames = 3});
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(out_);
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 3u);
  EXPECT_EQ(s->frames[1].source, "bun045.ply");
  ASSERT_TRUE(s->frames[1].world_from_camera);
  // bun045 is rotated about 34 degrees (data README), not 45.
  const double angle = Eigen::AngleAxisd(s->frames[1].world_from_camera->linear()).angle() * 180 / M_PI;
  EXPECT_NEAR(angle, 34.3, 1.0);
  auto pts = read_ply_points(out_ / s->frames[0].points);
  ASSERT_TRUE(pts) << pts.error().message;
  EXPECT_EQ(pts->points.size(), 40256u);
}

TEST_F(ImportTest, MiddleburyGivenCameras) {
  auto r = import_dataset("middlebury", data_ / "middlebury_dino_ring", out_, {.stride = 4});
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(out_);
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 4u);
  // The bounding-box centre of the dino projects inside every image.
  const Eigen::Vector3d centre(-0.0255, 0.0247, -0.0212);
  for (const auto& f : s->frames) {
    auto K = s->color_intrinsics(f);
    ASSERT_TRUE(K && f.world_from_camera);
    auto px = K->project(f.world_from_camera->inverse() * centre);
    ASSERT_TRUE(px);
    EXPECT_TRUE(K->contains(*px)) << px->transpose();
  }
}

TEST_F(ImportTest, RealSenseAlignedDepth) {
  auto r = import_dataset("realsense", data_ / "realsense_d435_bear" / "bear", out_, {});
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(out_);
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(s->frames.size(), 8u);
  auto d = load_depth(*s, s->frames[0]);
  ASSERT_TRUE(d);
  size_t valid = 0;
  for (auto v : d->data) valid += v != 0;
  EXPECT_GT(valid, d->pixels() / 4);
}

TEST_F(ImportTest, SevenScenesPosesAndInvalidDepth) {
  auto r = import_dataset("7scenes", data_ / "7scenes_kitchen_0_199", out_, {.stride = 50});
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(out_);
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(s->frames.size(), 4u);
  EXPECT_EQ(s->layout, Layout::kCameraCentre);
  auto d = load_depth(*s, s->frames[0]);
  ASSERT_TRUE(d);
  for (auto v : d->data) ASSERT_NE(v, 65535);
}

TEST_F(ImportTest, BadInputIsAClearError) {
  auto r = import_dataset("stanford", data_ / "nope.conf", out_, {});
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("not found"), std::string::npos);
  r = import_dataset("kinect", data_, out_, {});
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("unknown data set"), std::string::npos);
}

}  // namespace
}  // namespace s2r
