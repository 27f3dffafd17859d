#include "core/camera_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/calib3d.hpp>

namespace s2r {
namespace {

Intrinsics lens() {
  Intrinsics k;
  k.width = 640; k.height = 480; k.fx = 600; k.fy = 601.5; k.cx = 322.6; k.cy = 237.2;
  k.dist = {-0.12, 0.05, 0.0008, -0.0005, 0.01};
  return k;
}

TEST(CameraModel, ProjectionAgreesWithOpenCV) {
  const Intrinsics k = lens();
  std::vector<cv::Point3d> pts;
  for (double x = -0.4; x <= 0.4; x += 0.2)
    for (double y = -0.3; y <= 0.3; y += 0.15) pts.emplace_back(x, y, 1.0 + x * 0.3);
  std::vector<cv::Point2d> cv_px;
  cv::Mat K = (cv::Mat_<double>(3, 3) << k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1);
  cv::Mat D = (cv::Mat_<double>(1, 5) << k.dist[0], k.dist[1], k.dist[2], k.dist[3], k.dist[4]);
  cv::projectPoints(pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, cv_px);
  for (size_t i = 0; i < pts.size(); ++i) {
    auto p = k.project({pts[i].x, pts[i].y, pts[i].z});
    ASSERT_TRUE(p);
    EXPECT_NEAR(p->x(), cv_px[i].x, 1e-9);
    EXPECT_NEAR(p->y(), cv_px[i].y, 1e-9);
  }
}

TEST(CameraModel, UnprojectInvertsProjectOverTheImage) {
  const Intrinsics k = lens();
  double worst = 0;
  for (int y = 0; y < k.height; y += 7)
    for (int x = 0; x < k.width; x += 7) {
      auto p = k.unproject({double(x), double(y)}, 0.8);
      ASSERT_TRUE(p) << x << "," << y;
      EXPECT_NEAR(p->z(), 0.8, 1e-15);
      worst = std::max(worst, (*k.project(*p) - Eigen::Vector2d(x, y)).norm());
    }
  EXPECT_LT(worst, 1e-6);
}

TEST(CameraModel, StiffCasesGiveNoNaN) {
  Intrinsics k = lens();
  EXPECT_FALSE(k.project({0.1, 0.1, 0.0}));   // on the camera plane
  EXPECT_FALSE(k.project({0.1, 0.1, -1.0}));  // behind
  k.dist = {-0.9, 0.0, 0, 0, 0};              // strong barrel: radius folds back
  auto r = k.ray({-5000.0, -5000.0});          // far outside the field
  if (r) {
    EXPECT_TRUE(r->allFinite());
  }
  Intrinsics bad = lens();
  bad.fx = std::nan("");
  auto st = bad.validate("color");
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("color.fx"), std::string::npos);
  bad = lens();
  bad.fy = 0;
  EXPECT_FALSE(bad.validate("x"));
}

TEST(CameraModel, RotationAboutAxisKeepsTheAxisFixed) {
  const Eigen::Vector3d dir = Eigen::Vector3d(0.1, -0.9, -0.4).normalized(), point(0.02, 0.1, 0.5);
  const auto t = rotation_about_axis(dir, point, 1.3);
  EXPECT_LT((t * (point + 0.37 * dir) - (point + 0.37 * dir)).norm(), 1e-12);
  EXPECT_NEAR(Eigen::AngleAxisd(t.linear()).angle(), 1.3, 1e-12);
  // Near 180 degrees the rotation stays proper.
  const auto h = rotation_about_axis(dir, point, M_PI - 1e-12);
  EXPECT_NEAR(h.linear().determinant(), 1.0, 1e-12);
}

}  // namespace
}  // namespace s2r
