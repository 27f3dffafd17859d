// Image files through OpenImageIO: PNG (8/16-bit), JPEG, EXR, HDR, ...
// Reads validate fully (a truncated or corrupt file is an error naming the
// file); writes are atomic.
#pragma once

#include <filesystem>
#include <map>
#include <string>

#include "core/image.h"
#include "core/result.h"

namespace s2r {

struct ImageInfo {
  int width = 0, height = 0, channels = 0;
  int bits = 0;  // bits per channel as stored
};

Result<ImageInfo> probe_image(const std::filesystem::path& path);
Result<ImageU8> read_image_u8(const std::filesystem::path& path);
Result<ImageU16> read_image_u16(const std::filesystem::path& path);  // 16-bit PNG depth
Result<ImageF> read_image_float(const std::filesystem::path& path);  // EXR/HDR or scaled

// PNG effort: kCompact deflates (level 1, SUB filter); kFast stores without
// compression so a capture keeps up with the camera (s2r bench capture).
enum class PngEffort { kCompact, kFast };

Status write_image(const std::filesystem::path& path, const ImageU8& image, PngEffort effort = PngEffort::kCompact);
Status write_image(const std::filesystem::path& path, const ImageU16& image, PngEffort effort = PngEffort::kCompact);
Status write_image(const std::filesystem::path& path, const ImageF& image);  // EXR

// OpenEXR with the product's own metadata: `attributes` are stored as string
// attributes (names like "s2r:size") and read back by read_exr; `half` stores
// 16-bit floats (values beyond 65504 become infinite: the caller checks).
using ExrAttributes = std::map<std::string, std::string>;
Status write_exr(const std::filesystem::path& path, const ImageF& image, const ExrAttributes& attributes, bool half);
Result<ImageF> read_exr(const std::filesystem::path& path, ExrAttributes* attributes);  // all "s2r:" attributes

// Camera textures for the viewer (docs/formats.md, "Model"): one OpenEXR file
// with half-float R, G, B, A (colour 0..1, A = 1 where the fused geometry is
// hit) and a float Z channel holding the distance d along the pixel's ray in
// metres (0 where nothing is hit).
struct RgbazImage {
  ImageU8 rgba;   // 4 channels
  ImageF distance;  // 1 channel
};
Status write_rgbaz(const std::filesystem::path& path, const RgbazImage& image);

// White text into an 8-bit RGB(A) image (OpenImageIO + a DejaVu font from
// fonts-dejavu-core); `baseline` is the text's baseline row. For on-screen
// status lines.
Status draw_text(ImageU8& image, int x, int baseline, int size_px, const std::string& text);
Result<RgbazImage> read_rgbaz(const std::filesystem::path& path);

}  // namespace s2r
