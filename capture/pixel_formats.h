// Raw camera formats <-> images. Decoders validate sizes (a short buffer is an
// error, never a read past its end).
//   YUYV   4:2:2, BT.601 limited range (the UVC default); integer reference conversion
//   MJPEG  JPEG per frame (OpenCV's decoder, libjpeg-turbo underneath)
//   GREY   8-bit luminance
//   Z16    16-bit depth, little-endian, device units (D400: 1 mm)
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "core/image.h"
#include "core/result.h"

namespace s2r {

constexpr uint32_t fourcc(char a, char b, char c, char d) {
  return uint32_t(uint8_t(a)) | uint32_t(uint8_t(b)) << 8 | uint32_t(uint8_t(c)) << 16 | uint32_t(uint8_t(d)) << 24;
}
inline constexpr uint32_t kFourccYUYV = fourcc('Y', 'U', 'Y', 'V');
inline constexpr uint32_t kFourccMJPG = fourcc('M', 'J', 'P', 'G');
inline constexpr uint32_t kFourccGREY = fourcc('G', 'R', 'E', 'Y');
// B, G, R bytes: what libcamera's RGB888 (DRM_FORMAT_RGB888) is in memory.
inline constexpr uint32_t kFourccBGR3 = fourcc('B', 'G', 'R', '3');
inline constexpr uint32_t kFourccZ16 = fourcc('Z', '1', '6', ' ');
std::string fourcc_name(uint32_t f);
bool is_depth_format(uint32_t f);

// stride: bytes per row (0 = packed).
Result<ImageU8> yuyv_to_rgb(std::string_view data, int width, int height, int stride = 0);
Result<ImageU8> mjpeg_to_rgb(std::string_view data, int width, int height);
Result<ImageU8> grey_to_rgb(std::string_view data, int width, int height, int stride = 0);
Result<ImageU16> z16_to_depth(std::string_view data, int width, int height, int stride = 0);

// Encoders for the simulated camera and fixtures (the device side).
std::string rgb_to_yuyv(const ImageU8& rgb);
std::string rgb_to_mjpeg(const ImageU8& rgb, int quality = 90);
std::string rgb_to_grey(const ImageU8& rgb);
std::string depth_to_z16(const ImageU16& depth);

}  // namespace s2r
