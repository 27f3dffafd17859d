#include "capture/import_datasets.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
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

// A COLMAP text model written here (three camera models, one image without
// 2-D points), imported; then the same model converted to binary by COLMAP's
// own model_converter and imported again: the same cameras and poses.
TEST(ImportColmap, TextAndColmapsOwnBinaryGiveTheSameSession) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_import_colmap_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "images");
  fs::create_directories(dir / "txt");
  ASSERT_TRUE(write_image(dir / "images" / "a.png", ImageU8(40, 30, 3, 90)));
  ASSERT_TRUE(write_image(dir / "images" / "b.png", ImageU8(40, 30, 3, 90)));
  ASSERT_TRUE(write_image(dir / "images" / "c.png", ImageU8(64, 48, 3, 90)));
  std::ofstream(dir / "txt" / "cameras.txt") << "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                                             << "1 SIMPLE_RADIAL 40 30 50 20 15 0.01\n"
                                             << "2 OPENCV 64 48 60 61 32 24 0.1 -0.02 0.001 0.002\n"
                                             << "7 PINHOLE 40 30 52 53 20.5 14.5\n";
  // Image 2 is a quarter turn about y, 1 unit back; image 5 has no 2-D points.
  const double h = std::sqrt(0.5);
  std::ofstream(dir / "txt" / "images.txt") << "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
                                            << "3 1 0 0 0 0 0 2 1 a.png\n10 12 1\n"
                                            << "2 " << h << " 0 " << h << " 0 0 0 1 2 c.png\n5 6 -1 7 8 1\n"
                                            << "5 1 0 0 0 0.1 0 3 7 b.png\n\n";
  std::ofstream(dir / "txt" / "points3D.txt") << "1 0 0 0 255 0 0 0.5 3 0 2 0\n";
  auto t = import_dataset("colmap", dir / "txt", dir / "from_text", {.images = dir / "images"});
  ASSERT_TRUE(t) << t.error().message;
  EXPECT_EQ(t->counts.at("points3d"), 1);
  auto s = load_session(dir / "from_text");
  ASSERT_TRUE(s) << s.error().message;
  ASSERT_EQ(s->frames.size(), 3u);
  EXPECT_EQ(s->frames[1].source, "c.png");
  const Intrinsics Ka = *s->frames[0].intrinsics, Kc = *s->frames[1].intrinsics, Kb = *s->frames[2].intrinsics;
  EXPECT_EQ(Ka.fx, 50);
  EXPECT_EQ(Ka.fy, 50);
  EXPECT_EQ(Ka.cx, 19.5);  // COLMAP's pixel centres at +0.5
  EXPECT_EQ(Ka.dist[0], 0.01);
  EXPECT_EQ(Kc.fy, 61);
  EXPECT_EQ(Kc.cy, 23.5);
  EXPECT_EQ(Kc.dist[3], 0.002);
  EXPECT_EQ(Kb.fx, 52);
  EXPECT_EQ(Kb.cx, 20.0);
  // cam_from_world inverted: image a's camera centre is at z = -2.
  EXPECT_NEAR((s->frames[0].world_from_camera->translation() - Eigen::Vector3d(0, 0, -2)).norm(), 0, 1e-12);
  // The world origin is 1 unit in front of image c's camera.
  EXPECT_NEAR((s->frames[1].world_from_camera->inverse() * Eigen::Vector3d::Zero()).z(), 1.0, 1e-12);

  if (std::system("command -v colmap >/dev/null 2>&1") != 0) GTEST_SKIP() << "COLMAP is not installed (scripts/setup installs it)";
  fs::create_directories(dir / "bin");
  const std::string cmd = "colmap model_converter --input_path '" + (dir / "txt").string() + "' --output_path '" +
                          (dir / "bin").string() + "' --output_type BIN >/dev/null 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  ASSERT_TRUE(fs::exists(dir / "bin" / "images.bin"));
  auto b = import_dataset("colmap", dir / "bin", dir / "from_bin", {.images = dir / "images"});
  ASSERT_TRUE(b) << b.error().message;
  EXPECT_EQ(std::get<std::string>(b->params.at("encoding")), "binary");
  EXPECT_EQ(b->counts.at("points3d"), 1);
  auto sb = load_session(dir / "from_bin");
  ASSERT_TRUE(sb) << sb.error().message;
  ASSERT_EQ(sb->frames.size(), 3u);
  // COLMAP writes images in its own order: match them by name.
  for (const auto& ft : s->frames) {
    const auto fb = std::find_if(sb->frames.begin(), sb->frames.end(), [&](const Frame& f) { return f.source == ft.source; });
    ASSERT_NE(fb, sb->frames.end()) << ft.source;
    const Intrinsics &x = *ft.intrinsics, &y = *fb->intrinsics;
    EXPECT_EQ(x.fx, y.fx);
    EXPECT_EQ(x.fy, y.fy);
    EXPECT_EQ(x.cx, y.cx);
    EXPECT_EQ(x.cy, y.cy);
    for (size_t k = 0; k < 5; ++k) EXPECT_EQ(x.dist[k], y.dist[k]);
    EXPECT_LT((ft.world_from_camera->matrix() - fb->world_from_camera->matrix()).norm(), 1e-9) << ft.source;
  }
  fs::remove_all(dir);
}

TEST(ImportColmap, BadModelsAreClearErrors) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_import_colmapbad_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  ASSERT_TRUE(write_image(dir / "a.png", ImageU8(40, 30, 3, 90)));
  auto with = [&](const std::string& cameras, const std::string& images) {
    std::ofstream(dir / "cameras.txt") << cameras;
    std::ofstream(dir / "images.txt") << images;
    fs::remove_all(dir / "session");
    return import_dataset("colmap", dir, dir / "session", {});
  };
  auto r = with("1 FOV 40 30 50 20 15 0.1\n", "1 1 0 0 0 0 0 1 1 a.png\n\n");
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, ErrorCode::unsupported);
  EXPECT_NE(r.error().message.find("FOV"), std::string::npos);
  r = with("1 PINHOLE 40 30 50 20 15\n", "1 1 0 0 0 0 0 1 1 a.png\n\n");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("4 parameters, got 3"), std::string::npos) << r.error().message;
  r = with("1 SIMPLE_PINHOLE 40 30 50 20 15\n", "1 2 0 0 0 0 0 1 1 a.png\n\n");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("quaternion"), std::string::npos) << r.error().message;
  r = with("1 SIMPLE_PINHOLE 40 30 50 20 15\n", "1 1 0 0 0 0 0 1 9 a.png\n\n");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("camera 9"), std::string::npos) << r.error().message;
  EXPECT_FALSE(fs::exists(dir / "session" / "session.json"));
  r = with("1 SIMPLE_PINHOLE 80 60 50 20 15\n", "1 1 0 0 0 0 0 1 1 a.png\n\n");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("40x30"), std::string::npos) << r.error().message;
  r = with("1 SIMPLE_PINHOLE 40 30 50 20 15\n", "1 1 0 0 0 0 0 1 1 ../../etc/passwd\n\n");
  ASSERT_FALSE(r);
  // A truncated binary file.
  fs::remove(dir / "cameras.txt");
  fs::remove(dir / "images.txt");
  std::ofstream(dir / "cameras.bin", std::ios::binary) << std::string("\x05\0\0\0\0\0\0\0\x01", 9);
  std::ofstream(dir / "images.bin", std::ios::binary) << std::string(8, '\0');
  r = import_dataset("colmap", dir, dir / "session", {});
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, ErrorCode::format);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace s2r
