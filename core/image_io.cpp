#include "core/image_io.h"

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include <emmintrin.h>
#include <libdeflate.h>
#include <png.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
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
  if (!fs::exists(path, ec)) return fail(ErrorCode::not_found, "'" + path.string() + "': image file not found");
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
    return fail(ErrorCode::format, "'" + path.string() + "': truncated or corrupt image (" +
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

// The depth frames as capture writes them (16-bit greyscale, not
// interlaced), decoded faster than libpng does (the rig bunny's 24 frames:
// `s2r reconstruct`'s load step 0.030 -> 0.018 s): libdeflate inflates the
// pixel stream and computes each chunk's CRC-32, and the rows are unfiltered
// here with SSE2 where a filter allows it (libpng undoes the Sub filter
// capture writes one byte after another). Only a file read without a fault
// is taken: any other file, and every error (a bad CRC, a short stream, an
// unknown filter, a chunk out of place, an interlaced or huge image) is
// left to libpng, whose verdict and messages stand.
class FastGray16 {
 public:
  static bool signed_png(const std::vector<uint8_t>& file) {
    static constexpr uint8_t kSignature[8] = {137, 'P', 'N', 'G', 13, 10, 26, 10};
    return file.size() >= 8 && std::memcmp(file.data(), kSignature, 8) == 0;
  }
  // nullopt: not taken (libpng decides).
  static std::optional<ImageU16> decode(const std::vector<uint8_t>& file) {
    if (!signed_png(file)) return std::nullopt;
    uint32_t width = 0, height = 0;
    std::vector<uint8_t> stream;  // the IDAT chunks' data, joined
    bool header = false, idat_done = false, end = false;
    for (size_t at = 8; !end;) {
      if (file.size() - at < 12) return std::nullopt;
      const uint32_t length = be32(&file[at]);
      if (length > 0x7fffffffu || length > file.size() - at - 12) return std::nullopt;
      const uint8_t* type = &file[at + 4];
      for (int k = 0; k < 4; ++k)
        if (type[k] > 127 || !std::isalpha(type[k])) return std::nullopt;  // not a chunk name
      const uint8_t* data = type + 4;
      if (libdeflate_crc32(0, type, 4 + size_t(length)) != be32(data + length)) return std::nullopt;
      const bool critical = !(type[0] & 0x20);
      if (!header) {
        // IHDR first: 16-bit greyscale, compression, filter method 0, not interlaced, at most 2^14 a side.
        if (std::memcmp(type, "IHDR", 4) != 0 || length != 13) return std::nullopt;
        width = be32(data), height = be32(data + 4);
        if (width == 0 || height == 0 || width > (1u << 14) || height > (1u << 14)) return std::nullopt;
        if (data[8] != 16 || data[9] != 0 || data[10] != 0 || data[11] != 0 || data[12] != 0) return std::nullopt;
        header = true;
      } else if (std::memcmp(type, "IDAT", 4) == 0) {
        if (idat_done) return std::nullopt;  // IDAT chunks must follow one another
        stream.insert(stream.end(), data, data + length);
      } else if (std::memcmp(type, "IEND", 4) == 0) {
        if (length != 0) return std::nullopt;
        end = true;
      } else {
        if (critical) return std::nullopt;  // PLTE or an unknown critical chunk
        if (!stream.empty()) idat_done = true;
      }
      at += 12 + size_t(length);
    }
    if (stream.empty()) return std::nullopt;
    const size_t row_bytes = size_t(width) * 2;
    std::vector<uint8_t> raw(size_t(height) * (row_bytes + 1));
    struct Inflater {
      libdeflate_decompressor* d = libdeflate_alloc_decompressor();
      ~Inflater() { libdeflate_free_decompressor(d); }
    };
    thread_local Inflater inflater;
    size_t got = 0;
    if (!inflater.d ||
        libdeflate_zlib_decompress(inflater.d, stream.data(), stream.size(), raw.data(), raw.size(), &got) != LIBDEFLATE_SUCCESS ||
        got != raw.size())
      return std::nullopt;
    ImageU16 img(int(width), int(height), 1);
    // Two row buffers, each the other's row above in turn (zeros above the first).
    std::vector<uint8_t> rows(2 * row_bytes, 0);
    uint8_t *row = rows.data(), *prior = rows.data() + row_bytes;
    for (size_t y = 0; y < height; ++y) {
      const uint8_t* in = &raw[y * (row_bytes + 1)];
      if (!unfilter(in[0], in + 1, prior, row, row_bytes)) return std::nullopt;
      // Big-endian samples to native, eight at a time.
      uint16_t* out = img.data.data() + y * width;
      size_t x = 0;
      if constexpr (std::endian::native == std::endian::little)
        for (; x + 8 <= width; x += 8) {
          const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + 2 * x));
          _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), _mm_or_si128(_mm_slli_epi16(v, 8), _mm_srli_epi16(v, 8)));
        }
      for (; x < width; ++x) out[x] = uint16_t(row[2 * x] << 8 | row[2 * x + 1]);
      std::swap(row, prior);
    }
    return img;
  }

 private:
  static uint32_t be32(const uint8_t* p) { return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | p[3]; }

  // One row's filter undone (two bytes a pixel): `in` filtered, `prior` the
  // row above unfiltered (zeros for the first), `out` n bytes.
  static bool unfilter(uint8_t filter, const uint8_t* in, const uint8_t* prior, uint8_t* out, size_t n) {
    constexpr size_t bpp = 2;
    switch (filter) {
      case 0: std::memcpy(out, in, n); return true;
      case 1: {  // Sub: each byte plus the one two before, as a prefix sum of 16-byte blocks
        __m128i carry = _mm_setzero_si128();  // the previous block's last pixel, in every lane
        size_t i = 0;
        for (; i + 16 <= n; i += 16) {
          __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + i));
          v = _mm_add_epi8(v, _mm_slli_si128(v, 2));
          v = _mm_add_epi8(v, _mm_slli_si128(v, 4));
          v = _mm_add_epi8(v, _mm_slli_si128(v, 8));
          v = _mm_add_epi8(v, carry);
          _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i), v);
          carry = _mm_shufflehi_epi16(v, 0xff);
          carry = _mm_unpackhi_epi64(carry, carry);
        }
        for (; i < n; ++i) out[i] = uint8_t(in[i] + (i >= bpp ? out[i - bpp] : 0));
        return true;
      }
      case 2: {  // Up
        size_t i = 0;
        for (; i + 16 <= n; i += 16)
          _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i),
                           _mm_add_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(in + i)),
                                        _mm_loadu_si128(reinterpret_cast<const __m128i*>(prior + i))));
        for (; i < n; ++i) out[i] = uint8_t(in[i] + prior[i]);
        return true;
      }
      case 3:  // Average
        for (size_t i = 0; i < n; ++i) out[i] = uint8_t(in[i] + ((i >= bpp ? out[i - bpp] : 0) + prior[i]) / 2);
        return true;
      case 4:  // Paeth
        for (size_t i = 0; i < n; ++i) {
          const int a = i >= bpp ? out[i - bpp] : 0, b = prior[i], c = i >= bpp ? prior[i - bpp] : 0;
          const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
          out[i] = uint8_t(in[i] + (pa <= pb && pa <= pc ? a : pb <= pc ? b : c));
        }
        return true;
      default: return false;
    }
  }
};

// nullopt: not a 16-bit greyscale PNG (OpenImageIO reads it).
std::optional<Result<ImageU16>> read_png_gray16(const fs::path& path) {
  {
    // A PNG (its signature first) read whole for the fast decoder; libpng
    // reads it again where that declines.
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (f) {
      std::vector<uint8_t> file(8);
      bool read_ok = std::fread(file.data(), 1, 8, f) == 8 && FastGray16::signed_png(file);
      uint8_t buf[65536];
      if (read_ok)
        for (size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) file.insert(file.end(), buf, buf + n);
      read_ok = read_ok && !std::ferror(f);
      std::fclose(f);
      if (read_ok)
        if (auto img = FastGray16::decode(file)) return Result<ImageU16>(std::move(*img));
    }
  }
  PngReader r;
  r.file = std::fopen(path.c_str(), "rb");
  png_byte signature[8];
  if (!r.file || std::fread(signature, 1, 8, r.file) != 8 || png_sig_cmp(signature, 0, 8) != 0) return std::nullopt;
  r.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &r, png_failed, png_warned);
  if (r.png) r.info = png_create_info_struct(r.png);
  if (!r.png || !r.info) return fail("'" + path.string() + "': cannot set up libpng");
  auto corrupt = [&](const std::string& why) -> Result<ImageU16> {
    return fail(ErrorCode::format, "'" + path.string() + "': truncated or corrupt image (" + why + ")");
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
  if (!fs::exists(path, ec)) return fail(ErrorCode::not_found, "'" + path.string() + "': image file not found");
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
