// The marker calibration's clear errors (stiff cases): no dots, one frame,
// missing depth; and the calibration file carrying the measured angles, the
// session they belong to and the table radius. The real bear is in
// reconstruct/registration_data_test (it registers from them).
#include <gtest/gtest.h>

#include <filesystem>

#include "calibrate/table_markers.h"

namespace s2r {
namespace {

Intrinsics k640() {
  Intrinsics K;
  K.width = 64, K.height = 48, K.fx = K.fy = 60, K.cx = 31.5, K.cy = 23.5;
  return K;
}

TEST(TableMarkers, ClearErrors) {
  const Intrinsics K = k640();
  std::vector<ImageU8> black(3, ImageU8(64, 48, 3));
  std::vector<ImageU16> depth(3, ImageU16(64, 48, 1));
  for (auto& d : depth) std::fill(d.data.begin(), d.data.end(), uint16_t(500));
  auto r = calibrate_table_markers(black, depth, 0.001, K);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("dots"), std::string::npos) << r.error().message;
  r = calibrate_table_markers({black[0]}, {depth[0]}, 0.001, K);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("two frames"), std::string::npos) << r.error().message;
  r = calibrate_table_markers(black, {}, 0.001, K);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("depth"), std::string::npos) << r.error().message;
}

TEST(TableMarkers, CalibrationKeepsTheMeasuredAnglesAndRadius) {
  namespace fs = std::filesystem;
  const fs::path p = fs::temp_directory_path() / "s2r_markers_cal.json";
  Calibration c;
  TurntableAxis a;
  a.direction_camera = Eigen::Vector3d(0, -0.8, -0.6);
  a.point_camera = Eigen::Vector3d(0, 0, 0.3);
  a.frame_angles_deg = {0, -45.5, 90.25};
  a.frames_session = "bear";
  a.table_radius_m = 0.16;
  c.axis = a;
  ASSERT_TRUE(save_calibration(p, c));
  auto back = load_calibration(p);
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_EQ(back->axis->frame_angles_deg, a.frame_angles_deg);
  EXPECT_EQ(back->axis->frames_session, "bear");
  EXPECT_DOUBLE_EQ(back->axis->table_radius_m, 0.16);
  // Over the table: inside the cylinder and not below the plane.
  EXPECT_TRUE(back->axis->over_table(a.point_camera + 0.05 * a.direction_camera));
  EXPECT_FALSE(back->axis->over_table(a.point_camera - 0.05 * a.direction_camera));
  const Eigen::Vector3d side = a.direction_camera.unitOrthogonal();
  EXPECT_FALSE(back->axis->over_table(a.point_camera + 0.2 * side));
  // Angles apply only to their own session with as many frames.
  Session s;
  s.name = "bear";
  s.frames.resize(3);
  s.frames[1].table_angle_reported_deg = 7;
  EXPECT_TRUE(back->has_measured_angles(s));
  EXPECT_DOUBLE_EQ(back->frame_angle_deg(s, 1), -45.5);
  s.name = "other";
  EXPECT_FALSE(back->has_measured_angles(s));
  EXPECT_DOUBLE_EQ(back->frame_angle_deg(s, 1), 7);
  fs::remove(p);
}

}  // namespace
}  // namespace s2r
