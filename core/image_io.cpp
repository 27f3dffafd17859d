#include "core/image_io.h"

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imageio.h>

#include <cmath>

#include "core/atomic_file.h"

namespace s2r {
namespace fs = std::filesystem;
namespace oiio = OIIO;

namespace {

template <class T>
Result<Image<T>> read_as(const fs::path& path, oiio::TypeDesc type) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return fail("'" + path.string() + "': image file not found");
  auto in = oiio::ImageInput::open(path.string());
  if (!in) return fail("'" + path.string() + "': cannot open image: " + oiio::geterror());
  const oiio::ImageSpec& spec = in->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0)
    return fail("'" + path.string() + "': image has no pixels");
  Image<T> img(spec.width, spec.height, spec.nchannels);
  bool ok = in->read_image(0, 0, 0, spec.nchannels, type, img.data.data());
  std::string err = in->geterror();
  in->close();
  if (!ok || !err.empty())
    return fail("'" + path.string() + "': truncated or corrupt image (" +
                (err.empty() ? std::string("read failed") : err) + ")");
  return img;
}

template <class T>
Status write_as(const fs::path& path, const Image<T>& image, oiio::TypeDesc type,
                PngEffort effort = PngEffort::kCompact) {
  if (image.empty()) return fail("'" + path.string() + "': refusing to write an empty image");
  return write_via_temp(path, [&](const fs::path& tmp) -> Status {
    auto out = oiio::ImageOutput::create(tmp.string());
    if (!out) return fail("no image writer for '" + path.string() + "': " + oiio::geterror());
    oiio::ImageSpec spec(image.width, image.height, image.channels, type);
    if (type == oiio::TypeDesc::FLOAT) spec.attribute("compression", "zip");
    // Camera frames are noisy: deflate level 6 with adaptive filters costs ~7x
    // level 1 with one filter for a few percent of size (s2r bench capture).
    spec.attribute("png:compressionLevel", effort == PngEffort::kFast ? 0 : 1);
    spec.attribute("png:filter", 16);  // PNG_FILTER_SUB only
    if (!out->open(tmp.string(), spec)) return fail(out->geterror());
    if (!out->write_image(type, image.data.data())) return fail(out->geterror());
    if (!out->close()) return fail(out->geterror());
    return {};
  });
}

}  // namespace

Result<ImageInfo> probe_image(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return fail("'" + path.string() + "': image file not found");
  auto in = oiio::ImageInput::open(path.string());
  if (!in) return fail("'" + path.string() + "': cannot open image: " + oiio::geterror());
  const auto& s = in->spec();
  ImageInfo info{s.width, s.height, s.nchannels, static_cast<int>(s.format.size() * 8)};
  in->close();
  return info;
}

Result<ImageU8> read_image_u8(const fs::path& path) {
  return read_as<uint8_t>(path, oiio::TypeDesc::UINT8);
}
Result<ImageU16> read_image_u16(const fs::path& path) {
  return read_as<uint16_t>(path, oiio::TypeDesc::UINT16);
}
Result<ImageF> read_image_float(const fs::path& path) {
  auto img = read_as<float>(path, oiio::TypeDesc::FLOAT);
  if (!img) return img;
  return img;
}

Status write_image(const fs::path& path, const ImageU8& image, PngEffort effort) {
  return write_as(path, image, oiio::TypeDesc::UINT8, effort);
}
Status write_image(const fs::path& path, const ImageU16& image, PngEffort effort) {
  return write_as(path, image, oiio::TypeDesc::UINT16, effort);
}
Status write_image(const fs::path& path, const ImageF& image) {
  return write_as(path, image, oiio::TypeDesc::FLOAT);
}

}  // namespace s2r
