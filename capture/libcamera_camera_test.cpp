#include "capture/libcamera_camera.h"

#include <gtest/gtest.h>

namespace s2r {
namespace {

// The camera manager starts and stops cleanly whatever is attached.
TEST(Libcamera, ListsCamerasOrNone) {
  const auto cams = list_libcamera_cameras();
  RecordProperty("cameras", static_cast<int>(cams.size()));
  SUCCEED();
}

TEST(Libcamera, CaptureOrSkipWithAReason) {
  auto cam = LibcameraCamera::open("", 640, 480);
  if (!cam) {
    EXPECT_NE(cam.error().message.find("libcamera"), std::string::npos);
    GTEST_SKIP() << "no libcamera camera here: " << cam.error().message;
  }
  ASSERT_TRUE((*cam)->start());
  auto f = (*cam)->grab();
  ASSERT_TRUE(f) << f.error().message;
  EXPECT_EQ(f->rgb.width, (*cam)->width());
}

TEST(Libcamera, UnknownIdIsAClearError) {
  auto cam = LibcameraCamera::open("no-such-camera", 640, 480);
  ASSERT_FALSE(cam);
  EXPECT_NE(cam.error().message.find("libcamera"), std::string::npos);
}

}  // namespace
}  // namespace s2r
