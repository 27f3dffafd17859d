#include "core/image_io.h"

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include <png.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <optional>
#include <vector>

#include "core/atomic_file.h"

namespace s2r {
namespace fs = std::filesystem;
namespace oiio = OIIO;

namespace {

template <class T>
Result<Image<T>> read_as(const fs::path& path, oiio::TypeDesc type, ExrAttributes* attributes = nullptr) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return fail("'" + path.string() + "': image file not found");
  auto in = oiio::ImageInput::open(path.string());
  if (!in) return fail("'" + path.string() + "': cannot open image: " + oiio::geterror());
  const oiio::ImageSpec& spec = in->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0)
    return fail("'" + path.string() + "': image has no pixels");
  if (attributes)
    for (const auto& a : spec.extra_attribs)
      if (a.name().string().rfind("s2r:", 0) == 0 && a.type() == oiio::TypeDesc::STRING)
        (*attributes)[a.name().string()] = a.get_string();
  Image<T> img(spec.width, spec.height, spec.nchannels);
  bool ok = in->read_image(0, 0, 0, spec.nchannels, type, img.data.data());
  std::string err = in->geterror();
  in->close();
  if (!ok || !err.empty())
    return fail("'" + path.string() + "': truncated or corrupt image (" +
                (err.empty() ? std::string("read failed") : err) + ")");
  return img;
}

// 16-bit greyscale PNG (depth frames) read with libpng itself: the same
// values as OpenImageIO's PNG reader in less time (the rig bunny's 24 frames:
// `s2r reconstruct`'s load step 0.035 -> 0.025 s). libpng reports errors by
// longjmp, so every call that may fail runs in a frame without destructors
// (png_header, png_rows).
struct PngReader {
  std::FILE* file = nullptr;
  png_structp png = nullptr;
  png_infop info = nullptr;
  char message[256] = "";
  ~PngReader() {
    if (png) png_destroy_read_struct(&png, info ? &info : nullptr, nullptr);
    if (file) std::fclose(file);
  }
};

void png_failed(png_structp png, png_const_charp message) {
  auto* r = static_cast<PngReader*>(png_get_error_ptr(png));
  std::snprintf(r->message, sizeof r->message, "%s", message ? message : "libpng error");
  png_longjmp(png, 1);
}
void png_warned(png_structp, png_const_charp) {}  // e.g. an unknown ancillary chunk: the pixels are fine

bool png_header(PngReader& r, png_uint_32& width, png_uint_32& height, int& depth, int& colour) {
  if (setjmp(png_jmpbuf(r.png))) return false;
  png_init_io(r.png, r.file);
  png_set_sig_bytes(r.png, 8);
  png_read_info(r.png, r.info);
  width = png_get_image_width(r.png, r.info), height = png_get_image_height(r.png, r.info);
  depth = png_get_bit_depth(r.png, r.info), colour = png_get_color_type(r.png, r.info);
  return true;
}

bool png_rows(PngReader& r, png_bytep* rows) {
  if (setjmp(png_jmpbuf(r.png))) return false;
  if constexpr (std::endian::native == std::endian::little) png_set_swap(r.png);  // PNG stores big-endian
  png_set_interlace_handling(r.png);
  png_read_update_info(r.png, r.info);
  png_read_image(r.png, rows);
  png_read_end(r.png, nullptr);
  return true;
}

// nullopt: not a 16-bit greyscale PNG (OpenImageIO reads it).
std::optional<Result<ImageU16>> read_png_gray16(const fs::path& path) {
  PngReader r;
  r.file = std::fopen(path.c_str(), "rb");
  png_byte signature[8];
  if (!r.file || std::fread(signature, 1, 8, r.file) != 8 || png_sig_cmp(signature, 0, 8) != 0) return std::nullopt;
  r.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &r, png_failed, png_warned);
  if (r.png) r.info = png_create_info_struct(r.png);
  if (!r.png || !r.info) return fail("'" + path.string() + "': cannot set up libpng");
  auto corrupt = [&](const std::string& why) -> Result<ImageU16> {
    return fail("'" + path.string() + "': truncated or corrupt image (" + why + ")");
  };
  png_uint_32 width = 0, height = 0;
  int depth = 0, colour = 0;
  // 2^14 a side: a depth frame 16 times a 4K sensor's pixel count.
  png_set_user_limits(r.png, 1u << 14, 1u << 14);
  // Every chunk's CRC-32 is still checked (a changed byte of the pixel data
  // is an error); the zlib stream's own Adler-32 over the inflated rows adds
  // nothing to that and took a fifth of the decoding time.
#ifdef PNG_IGNORE_ADLER32
  png_set_option(r.png, PNG_IGNORE_ADLER32, PNG_OPTION_ON);
#endif
  if (!png_header(r, width, height, depth, colour)) return corrupt(r.message);
  if (depth != 16 || colour != PNG_COLOR_TYPE_GRAY) return std::nullopt;
  ImageU16 img(int(width), int(height), 1);
  std::vector<png_bytep> rows(height);
  for (png_uint_32 y = 0; y < height; ++y) rows[y] = reinterpret_cast<png_bytep>(img.data.data() + size_t(y) * width);
  if (!png_rows(r, rows.data())) return corrupt(r.message);
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
  if (auto png = read_png_gray16(path)) return std::move(*png);
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

Status write_exr(const fs::path& path, const ImageF& image, const ExrAttributes& attributes, bool half) {
  if (image.empty()) return fail("'" + path.string() + "': refusing to write an empty image");
  return write_via_temp(path, [&](const fs::path& tmp) -> Status {
    auto out = oiio::ImageOutput::create("exr");
    if (!out) return fail("no OpenEXR writer: " + oiio::geterror());
    oiio::ImageSpec spec(image.width, image.height, image.channels, half ? oiio::TypeDesc::HALF : oiio::TypeDesc::FLOAT);
    spec.attribute("compression", "zip");
    for (const auto& [name, value] : attributes) spec.attribute(name, value);
    if (!out->open(tmp.string(), spec)) return fail(out->geterror());
    if (!out->write_image(oiio::TypeDesc::FLOAT, image.data.data())) return fail(out->geterror());
    if (!out->close()) return fail(out->geterror());
    return {};
  });
}

Result<ImageF> read_exr(const fs::path& path, ExrAttributes* attributes) {
  return read_as<float>(path, oiio::TypeDesc::FLOAT, attributes);
}

Status write_rgbaz(const fs::path& path, const RgbazImage& image) {
  const ImageU8& c = image.rgba;
  const ImageF& d = image.distance;
  if (c.empty() || c.channels != 4 || d.channels != 1 || c.width != d.width || c.height != d.height)
    return fail("'" + path.string() + "': RGBA+Z texture needs a 4-channel colour image and a 1-channel distance of the same size");
  std::vector<float> px(c.pixels() * 5);
  for (size_t i = 0; i < c.pixels(); ++i) {
    for (int k = 0; k < 4; ++k) px[i * 5 + k] = c.data[i * 4 + k] / 255.f;
    px[i * 5 + 4] = d.data[i];
  }
  return write_via_temp(path, [&](const fs::path& tmp) -> Status {
    auto out = oiio::ImageOutput::create("exr");
    if (!out) return fail("no OpenEXR writer: " + oiio::geterror());
    oiio::ImageSpec spec(c.width, c.height, 5, oiio::TypeDesc::HALF);
    spec.channelnames = {"R", "G", "B", "A", "Z"};
    spec.alpha_channel = 3;
    spec.z_channel = 4;
    spec.channelformats = {oiio::TypeDesc::HALF, oiio::TypeDesc::HALF, oiio::TypeDesc::HALF, oiio::TypeDesc::HALF,
                           oiio::TypeDesc::FLOAT};
    spec.attribute("compression", "none");
    if (!out->open(tmp.string(), spec)) return fail(out->geterror());
    if (!out->write_image(oiio::TypeDesc::FLOAT, px.data())) return fail(out->geterror());
    if (!out->close()) return fail(out->geterror());
    return {};
  });
}

Result<RgbazImage> read_rgbaz(const fs::path& path) {
  auto all = read_as<float>(path, oiio::TypeDesc::FLOAT);
  if (!all) return std::unexpected(all.error());
  if (all->channels != 5) return fail("'" + path.string() + "': expected 5 channels (R G B A Z), found " + std::to_string(all->channels));
  RgbazImage out{ImageU8(all->width, all->height, 4), ImageF(all->width, all->height, 1)};
  for (size_t i = 0; i < all->pixels(); ++i) {
    for (int k = 0; k < 4; ++k) {
      const float v = all->data[i * 5 + k];
      if (!std::isfinite(v)) return fail("'" + path.string() + "': non-finite colour at pixel " + std::to_string(i));
      out.rgba.data[i * 4 + k] = static_cast<uint8_t>(std::lround(std::clamp(v, 0.f, 1.f) * 255.f));
    }
    const float z = all->data[i * 5 + 4];
    if (!std::isfinite(z) || z < 0) return fail("'" + path.string() + "': distance at pixel " + std::to_string(i) + " is not a finite value >= 0");
    out.distance.data[i] = z;
  }
  return out;
}

Status draw_text(ImageU8& image, int x, int baseline, int size_px, const std::string& text) {
  if (image.empty() || (image.channels != 3 && image.channels != 4)) return fail("draw_text: an RGB or RGBA image is needed");
  static const char* kFonts[] = {"/usr/share/fonts/truetype/dejavu/DejaVuSansMono.ttf",
                                 "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"};
  const char* font = nullptr;
  for (const char* f : kFonts)
    if (fs::exists(f)) {
      font = f;
      break;
    }
  if (!font) return fail("draw_text: no DejaVu font (apt-get install fonts-dejavu-core)");
  oiio::ImageSpec spec(image.width, image.height, image.channels, oiio::TypeDesc::UINT8);
  oiio::ImageBuf buf(spec, image.data.data());  // wraps the pixels
  const float white[4] = {1, 1, 1, 1};
  if (!oiio::ImageBufAlgo::render_text(buf, x, baseline, text, size_px, font, white))
    return fail("draw_text: " + buf.geterror());
  return {};
}

}  // namespace s2r
