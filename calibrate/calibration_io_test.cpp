#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>

#include "calibrate/calibration.h"
#include "core/atomic_file.h"
#include "core/json_fields.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

class CalibrationFile : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = fs::temp_directory_path() / ("s2r_calib_" + std::to_string(::getpid()) + ".json");
    Calibration c;
    Intrinsics k;
    k.width = 640; k.height = 480; k.fx = 532.8; k.fy = 532.9; k.cx = 342.5; k.cy = 233.9;
    k.dist = {-0.28, 0.07, 0.001, -0.0003, 0.1};
    c.color = SensorCalibration{k, 0.196, 13};
    c.color_from_depth = Eigen::Isometry3d(Eigen::Translation3d(0.025, 0, 0));
    c.color_from_depth_rms = 0.8;
    TurntableAxis a;
    a.direction_camera = Eigen::Vector3d(0, -0.9, -0.3).normalized();
    a.point_camera = Eigen::Vector3d(0, 0.05, 0.5);
    a.rms_m = 0.0004;
    a.step_angles_deg = {15.01, 14.98};
    c.axis = a;
    ASSERT_TRUE(save_calibration(path_, c));
  }
  void TearDown() override { fs::remove(path_); }
  std::string error_after(const std::function<void(nlohmann::json&)>& edit) {
    const auto original = *read_file(path_);
    auto j = *parse_json_file(path_);
    edit(j);
    EXPECT_TRUE(write_file_atomic(path_, j.dump()));
    auto c = load_calibration(path_);
    EXPECT_FALSE(c);
    EXPECT_TRUE(write_file_atomic(path_, original));
    return c ? "" : c.error().message;
  }
  fs::path path_;
};

TEST_F(CalibrationFile, RoundTrip) {
  auto c = load_calibration(path_);
  ASSERT_TRUE(c) << c.error().message;
  EXPECT_DOUBLE_EQ(c->color->intrinsics.fx, 532.8);
  EXPECT_DOUBLE_EQ(c->color->rms_px, 0.196);
  EXPECT_NEAR(c->color_from_depth->translation().x(), 0.025, 1e-12);
  EXPECT_EQ(c->axis->step_angles_deg.size(), 2u);
  // A frame pose is a rotation about the axis: points on the axis stay put.
  const auto w = c->world_from_camera_at(30, Layout::kObjectCentre);
  EXPECT_LT((w * c->axis->point_camera - c->axis->point_camera).norm(), 1e-12);
  EXPECT_NEAR(Eigen::AngleAxisd(w.linear()).angle(), 30 * M_PI / 180, 1e-12);
}

TEST_F(CalibrationFile, RejectsBadContentNamingTheField) {
  EXPECT_NE(error_after([](auto& j) { j["version"] = 7; }).find("version: unsupported version 7"), std::string::npos);
  EXPECT_NE(error_after([](auto& j) { j["color"]["intrinsics"]["fx"] = nullptr; }).find("color.intrinsics.fx"),
            std::string::npos);
  EXPECT_NE(error_after([](auto& j) { j["color"]["intrinsics"]["fy"] = -3; }).find("color.intrinsics.fy: must be > 0"),
            std::string::npos);
  EXPECT_NE(error_after([](auto& j) { j["turntable_axis"]["direction_camera"] = {0, 0, 2}; })
                .find("turntable_axis.direction_camera: must be a unit vector"),
            std::string::npos);
  EXPECT_NE(error_after([](auto& j) { j["color_from_depth"]["transform"][0] = 5.0; }).find("not a proper rotation"),
            std::string::npos);
}

TEST_F(CalibrationFile, TruncationsAreErrors) {
  const auto text = *read_file(path_);
  for (size_t n = 0; n + 1 < text.size(); n += 3) {
    ASSERT_TRUE(write_file_atomic(path_, text.substr(0, n)));
    auto c = load_calibration(path_);
    ASSERT_FALSE(c) << n;
    EXPECT_NE(c.error().message.find(path_.filename().string()), std::string::npos);
  }
}

}  // namespace
}  // namespace s2r
