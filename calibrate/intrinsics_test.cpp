// Intrinsics on OpenCV's own real sample photos and the stiff cases.
#include "calibrate/intrinsics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <random>

#include "core/image_io.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

std::vector<fs::path> chessboard_photos() {
  std::vector<fs::path> out;
  const fs::path dir = fs::path(S2R_DATA_DIR) / "opencv_chessboard";
  if (!fs::exists(dir)) return out;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.path().extension() == ".jpg") out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

IntrinsicsOptions chess() {
  IntrinsicsOptions o;
  o.board = *BoardSpec::parse("chessboard:9x6:0.025");
  return o;
}

TEST(Intrinsics, OpenCvSamplePhotosMatchOpenCvsExpectation) {
  const auto photos = chessboard_photos();
  if (photos.empty()) GTEST_SKIP() << "real data not found";
  auto r = calibrate_intrinsics_from_files(photos, chess());
  ASSERT_TRUE(r) << r.error().message;
  const auto& K = r->calibration.intrinsics;
  RecordProperty("rms_px", std::to_string(r->calibration.rms_px));
  RecordProperty("fx", std::to_string(K.fx));
  RecordProperty("fy", std::to_string(K.fy));
  EXPECT_NEAR(r->calibration.rms_px, 0.196, 0.01);
  EXPECT_NEAR(K.fx, 532.8, 2.0);
  EXPECT_NEAR(K.fy, 532.9, 2.0);
  EXPECT_GT(r->stddev[0], 0);
  EXPECT_LT(r->stddev[0], 5);
  for (const auto& v : r->views) EXPECT_TRUE(v.detected) << v.name;
}

TEST(Intrinsics, TwoViewsGiveABoundedAnswerAndAWarning) {
  auto photos = chessboard_photos();
  if (photos.empty()) GTEST_SKIP() << "real data not found";
  photos.resize(2);
  auto r = calibrate_intrinsics_from_files(photos, chess());
  ASSERT_TRUE(r) << r.error().message;
  const auto& K = r->calibration.intrinsics;
  EXPECT_TRUE(std::isfinite(K.fx) && std::isfinite(K.fy));
  EXPECT_NEAR(K.fx, 532.8, 60);  // bounded, not exact
  ASSERT_FALSE(r->report.warnings.empty());
  EXPECT_NE(r->report.warnings[0].find("only 2 views"), std::string::npos);
}

TEST(Intrinsics, NearlyParallelBoardsWarnOfDegeneracy) {
  // Synthetic views of one board, all nearly fronto-parallel: the focal length
  // and the distance trade off, which the fit must report, not hide.
  Intrinsics truth;
  truth.width = 640; truth.height = 480; truth.fx = 600; truth.fy = 600; truth.cx = 320; truth.cy = 240;
  std::vector<BoardDetection> views;
  for (int i = 0; i < 6; ++i) {
    BoardDetection d;
    d.found = true;
    const Eigen::Isometry3d pose = Eigen::Translation3d(-0.1 + 0.01 * i, -0.06, 0.5 + 0.02 * i) *
                                   Eigen::AngleAxisd(0.002 * i, Eigen::Vector3d::UnitX());
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 9; ++c) {
        const Eigen::Vector3d p(0.025 * c, 0.025 * r, 0);
        d.board_points.push_back(p.cast<float>());
        d.image_points.push_back(truth.project(pose * p)->cast<float>());
      }
    views.push_back(d);
  }
  auto r = calibrate_intrinsics(views, {}, 640, 480, chess());
  if (!r) {
    EXPECT_NE(r.error().message.find("diverged"), std::string::npos) << r.error().message;
    return;
  }
  EXPECT_TRUE(std::isfinite(r->calibration.intrinsics.fx));
  bool warned = false;
  for (const auto& w : r->report.warnings) warned |= w.find("nearly parallel") != std::string::npos;
  EXPECT_TRUE(warned) << "fx " << r->calibration.intrinsics.fx << " std " << r->stddev[0];
}

TEST(Intrinsics, MissingDetectionsAreSkippedAndTooFewIsAnError) {
  std::vector<BoardDetection> views(3);  // nothing detected
  auto r = calibrate_intrinsics(views, {}, 640, 480, chess());
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("at least 2 views"), std::string::npos);
}

TEST(Board, ParsesSpecsAndRejectsNonsense) {
  auto b = BoardSpec::parse("charuco:5x7:0.04:0.02");
  ASSERT_TRUE(b);
  EXPECT_EQ(b->kind, BoardSpec::Kind::kCharuco);
  EXPECT_EQ(b->dictionary, "DICT_6X6_250");
  EXPECT_FALSE(BoardSpec::parse("chessboard:9:0.025"));
  EXPECT_FALSE(BoardSpec::parse("chessboard:9x6:-1"));
  EXPECT_FALSE(BoardSpec::parse("charuco:5x7:0.04:0.05"));
  EXPECT_FALSE(BoardSpec::parse("circles:4x11:0.02"));
}

TEST(Board, CharucoDetectedInTheRealPhoto) {
  const fs::path photo = fs::path(S2R_DATA_DIR) / "opencv_charuco" / "choriginal.jpg";
  if (!fs::exists(photo)) GTEST_SKIP() << "real data not found";
  auto im = read_image_u8(photo);
  ASSERT_TRUE(im);
  auto d = detect_board(*im, *BoardSpec::parse("charuco:5x7:0.04:0.02:DICT_6X6_250"));
  ASSERT_TRUE(d) << d.error().message;
  ASSERT_TRUE(d->found);
  RecordProperty("charuco_corners", static_cast<int>(d->ids.size()));
  EXPECT_GE(d->ids.size(), 12u);  // a 5x7 board has 24 inner corners
  for (const auto& p : d->image_points) {
    EXPECT_GE(p.x(), 0);
    EXPECT_LT(p.x(), im->width);
  }
}

}  // namespace
}  // namespace s2r

namespace s2r {
namespace {

// Views of a synthetic board with 0.1 px noise; one seen at a grazing angle
// (80 degrees), whose corners a detector places badly (1.5 px noise).
TEST(Intrinsics, GrazingViewGivesABoundedAnswer) {
  Intrinsics truth;
  truth.width = 640; truth.height = 480; truth.fx = 600; truth.fy = 600; truth.cx = 320; truth.cy = 240;
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0, 1);
  std::vector<BoardDetection> views;
  const double tilts[] = {-35, -20, 0, 20, 35, 80};
  for (size_t i = 0; i < std::size(tilts); ++i) {
    BoardDetection d;
    d.found = true;
    const Eigen::Isometry3d pose = Eigen::Translation3d(-0.08, -0.05, 0.5) *
                                   Eigen::AngleAxisd(tilts[i] * M_PI / 180, Eigen::Vector3d(i % 2 ? 1 : 0, i % 2 ? 0 : 1, 0));
    const float sigma = tilts[i] > 60 ? 1.5f : 0.1f;
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 9; ++c) {
        const Eigen::Vector3d p(0.02 * c, 0.02 * r, 0);
        auto px = truth.project(pose * p);
        ASSERT_TRUE(px);
        d.board_points.push_back(p.cast<float>());
        d.image_points.push_back(px->cast<float>() + Eigen::Vector2f(sigma * noise(rng), sigma * noise(rng)));
      }
    views.push_back(d);
  }
  IntrinsicsOptions o = chess();
  o.fix_k3 = true;
  auto r = calibrate_intrinsics(views, {}, 640, 480, o);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_TRUE(std::isfinite(r->calibration.intrinsics.fx));
  EXPECT_NEAR(r->calibration.intrinsics.fx, 600, 6);  // within 1 %
  // The grazing view is the worst and is dropped when it hurts the fit.
  EXPECT_FALSE(r->views[5].used) << r->views[5].note;
}

}  // namespace
}  // namespace s2r
