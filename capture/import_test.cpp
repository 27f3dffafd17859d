#include "capture/import_datasets.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>

#include "capture/session.h"
#include "core/image_io.h"
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

TEST_F(ImportTest, NerfSplitsLandInOneWorldWithTheirMattes) {
  const fs::path lego = data_ / "nerf_synthetic_lego";
  if (!fs::exists(lego / "transforms_train.json")) GTEST_SKIP() << "no lego in " << data_;
  auto r = import_dataset("nerf", lego, out_ / "train", {.stride = 1, .max_frames = 2});
  ASSERT_TRUE(r) << r.error().message;
  auto v = import_dataset("nerf", lego, out_ / "val", {.stride = 1, .max_frames = 2, .split = "val"});
  ASSERT_TRUE(v) << v.error().message;
  for (const char* split : {"train", "val"}) {
    auto s = load_session(out_ / split);
    ASSERT_TRUE(s) << s.error().message;
    ASSERT_EQ(s->frames.size(), 2u);
    ASSERT_TRUE(s->background);
    EXPECT_EQ((*s->background)[0], 1.f);
    for (const auto& f : s->frames) {
      auto K = s->color_intrinsics(f);
      ASSERT_TRUE(K && f.world_from_camera);
      // camera_angle_x 0.6911112 at 800 px; Blender's centre at 400 is 399.5 with integer pixel centres.
      EXPECT_NEAR(K->fx, 1111.111, 0.01);
      EXPECT_EQ(K->cx, 399.5);
      // The scene is centred at the origin, about 4 units from every camera: it projects near the centre, in front.
      const Eigen::Vector3d o = f.world_from_camera->inverse() * Eigen::Vector3d::Zero();
      EXPECT_NEAR(o.z(), 4.03, 0.05);
      auto px = K->project(o);
      ASSERT_TRUE(px);
      EXPECT_LT((*px - Eigen::Vector2d(399.5, 399.5)).norm(), 5.0);
      // The photo composited on white under the matte; alpha 0 is white.
      auto c = load_color(*s, f);
      auto m = load_mask(*s, f);
      ASSERT_TRUE(c && m);
      ASSERT_EQ(m->channels, 1);
      size_t empty = 0, object = 0;
      for (size_t i = 0; i < m->pixels(); ++i) {
        if (m->data[i] == 0) {
          ++empty;
          EXPECT_EQ(c->data[i * 3], 255);
        }
        object += m->data[i] == 255;
      }
      EXPECT_GT(empty, m->pixels() / 2);
      EXPECT_GT(object, m->pixels() / 20);
    }
  }
}

// A nerfstudio-style file written here: fl_x/fl_y/cx/cy with distortion,
// a per-frame focal length, images without alpha, OpenGL camera axes.
TEST(ImportNerf, NerfstudioIntrinsicsAndOpenGlAxes) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_import_ns_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "images");
  ImageU8 img(8, 6, 3, 100);
  ASSERT_TRUE(write_image(dir / "images" / "a.png", img));
  ASSERT_TRUE(write_image(dir / "images" / "b.png", img));
  // Frame a: at (0, 0, 2) looking along -z (OpenGL identity rotation); frame b: its own focal length.
  const std::string pose = R"([[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]])";
  std::ofstream(dir / "transforms.json")
      << R"({"fl_x": 10, "fl_y": 11, "cx": 4, "cy": 3, "w": 8, "h": 6, "k1": 0.1, "p2": 0.01, "frames": [)"
      << R"({"file_path": "images/a.png", "transform_matrix": )" << pose << "},"
      << R"({"file_path": "images/b", "fl_x": 12, "transform_matrix": )" << pose << "}]}";
  auto r = import_dataset("nerf", dir, dir / "session", {});
  ASSERT_TRUE(r) << r.error().message;
  auto s = load_session(dir / "session");
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 2u);
  EXPECT_FALSE(s->background);  // no alpha: nothing composited
  EXPECT_TRUE(s->frames[0].mask.empty());
  const Intrinsics K0 = *s->color_intrinsics(s->frames[0]), K1 = *s->color_intrinsics(s->frames[1]);
  EXPECT_EQ(K0.fx, 10);
  EXPECT_EQ(K0.fy, 11);
  EXPECT_EQ(K0.cx, 3.5);
  EXPECT_EQ(K0.cy, 2.5);
  EXPECT_EQ(K0.dist[0], 0.1);
  EXPECT_EQ(K0.dist[3], 0.01);
  EXPECT_EQ(K1.fx, 12);
  // OpenGL looks along -z with y up; OpenCV along +z with y down.
  const Eigen::Isometry3d cw = s->frames[0].world_from_camera->inverse();
  EXPECT_NEAR((cw * Eigen::Vector3d::Zero()).z(), 2.0, 1e-12);
  EXPECT_LT((cw * Eigen::Vector3d(0, 1, 0)).y(), 0.0);  // world up is image up
  EXPECT_GT((cw * Eigen::Vector3d(1, 0, 0)).x(), 0.0);
  fs::remove_all(dir);
}

TEST(ImportNerf, BadFilesAreClearErrorsAndWriteNoSession) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_import_nsbad_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  ImageU8 img(8, 6, 3, 100);
  ASSERT_TRUE(write_image(dir / "a.png", img));
  auto with = [&](const std::string& json) {
    std::ofstream(dir / "transforms.json") << json;
    fs::remove_all(dir / "session");
    return import_dataset("nerf", dir, dir / "session", {});
  };
  const std::string id = R"([[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]])";
  auto r = with(R"({"camera_angle_x": 0.7, "frames": [{"file_path": "missing", "transform_matrix": )" + id + "}]}");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("missing"), std::string::npos) << r.error().message;
  EXPECT_FALSE(fs::exists(dir / "session" / "session.json"));
  r = with(R"({"camera_angle_x": 0.7, "frames": [{"file_path": "a.png", "transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]}]})");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("rotation"), std::string::npos) << r.error().message;
  r = with(R"({"frames": [{"file_path": "a.png", "transform_matrix": )" + id + "}]}");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("fl_x"), std::string::npos) << r.error().message;
  r = with(R"({"camera_angle_x": 0.7, "w": 16, "frames": [{"file_path": "a.png", "transform_matrix": )" + id + "}]}");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("8x6"), std::string::npos) << r.error().message;
  r = with(R"({"camera_angle_x": 0.7, "frames": []})");
  ASSERT_FALSE(r);
  r = import_dataset("nerf", dir, dir / "session2", {.split = "test"});
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, ErrorCode::not_found);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace s2r
