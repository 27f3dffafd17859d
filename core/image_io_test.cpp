// Depth PNGs: 16-bit greyscale files are decoded by the fast reader
// (libdeflate, rows unfiltered here) or, where it declines, by libpng; any
// other image through OpenImageIO. All give the values written (every PNG
// filter, odd widths, real frames from another writer), and a bad file gives
// a readable error.
#include "core/image_io.h"

#include <gtest/gtest.h>
#include <png.h>
#include <unistd.h>
#include <zlib.h>

#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <fstream>
#include <iterator>

namespace s2r {
namespace {
namespace fs = std::filesystem;

class ImageIo : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("s2r_image_io_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string bytes(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(f), {}};
  }
  void put(const fs::path& p, const std::string& b) { std::ofstream(p, std::ios::binary) << b; }
  fs::path dir_;
};

ImageU16 ramp(int w, int h) {
  ImageU16 img(w, h, 1);
  for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = uint16_t(i * 2654435761u >> 16);
  img.data[0] = 0, img.data[1] = 65535;
  return img;
}

// Writes a 16-bit greyscale PNG with libpng itself, every row with the given
// filters (PNG_FILTER_*), optionally interlaced and with a text chunk before
// the pixels. In a frame without destructors: libpng reports errors by longjmp.
bool write_png16(const char* path, const ImageU16& img, int filters, bool interlaced, bool text) {
  std::FILE* f = std::fopen(path, "wb");
  if (!f) return false;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  bool ok = false;
  if (png && info && !setjmp(png_jmpbuf(png))) {
    png_init_io(png, f);
    png_set_IHDR(png, info, png_uint_32(img.width), png_uint_32(img.height), 16, PNG_COLOR_TYPE_GRAY,
                 interlaced ? PNG_INTERLACE_ADAM7 : PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_filter(png, PNG_FILTER_TYPE_BASE, filters);
    png_text t{};
    t.compression = PNG_TEXT_COMPRESSION_NONE, t.key = const_cast<char*>("Comment"), t.text = const_cast<char*>("test");
    if (text) png_set_text(png, info, &t, 1);
    png_write_info(png, info);
    png_set_swap(png);  // little-endian samples in memory
    std::vector<png_bytep> rows(size_t(img.height));
    for (int y = 0; y < img.height; ++y)
      rows[size_t(y)] = reinterpret_cast<png_bytep>(const_cast<uint16_t*>(img.data.data() + size_t(y) * size_t(img.width)));
    png_write_image(png, rows.data());
    png_write_end(png, nullptr);
    ok = true;
  }
  png_destroy_write_struct(&png, &info);
  std::fclose(f);
  return ok;
}

TEST_F(ImageIo, EveryPngFilterAndWidthDecodes) {
  // Widths around the 16-byte blocks the Sub and Up filters are undone in.
  const int filters[] = {PNG_FILTER_NONE, PNG_FILTER_SUB, PNG_FILTER_UP, PNG_FILTER_AVG, PNG_FILTER_PAETH, PNG_ALL_FILTERS};
  for (int w : {1, 7, 8, 9, 16, 33, 640})
    for (int filter : filters)
      for (int variant = 0; variant < 3; ++variant) {  // plain, a text chunk first, interlaced (libpng's)
        const ImageU16 img = ramp(w, 6);
        const fs::path p = dir_ / "f.png";
        ASSERT_TRUE(write_png16(p.c_str(), img, filter, variant == 2, variant == 1));
        auto back = read_image_u16(p);
        ASSERT_TRUE(back) << back.error().message;
        EXPECT_EQ(back->data, img.data) << "width " << w << ", filters " << filter << ", variant " << variant;
      }
}

TEST_F(ImageIo, RealDepthFramesReadAsOpenImageIoReadsThem) {
  // The RealSense bear's depth frames, written by another program.
  const fs::path bear = fs::path(S2R_DATA_DIR) / "realsense_d435_bear";
  if (!fs::exists(bear)) GTEST_SKIP() << "no " << bear;
  int frames = 0;
  for (const auto& e : fs::recursive_directory_iterator(bear)) {
    const std::string name = e.path().filename().string();
    if (e.path().extension() != ".png" || name.find("depth") == std::string::npos || frames >= 4) continue;
    auto fast = read_image_u16(e.path());
    auto oiio = read_image_float(e.path());
    ASSERT_TRUE(fast && oiio) << e.path();
    ASSERT_EQ(fast->data.size(), oiio->data.size());
    for (size_t i = 0; i < fast->data.size(); ++i)
      ASSERT_EQ(fast->data[i], uint16_t(std::lround(oiio->data[i] * 65535.f))) << e.path() << " sample " << i;
    ++frames;
  }
  EXPECT_GT(frames, 0);
}

TEST_F(ImageIo, DepthPngRoundTripsAtBothEfforts) {
  const ImageU16 img = ramp(37, 23);
  for (PngEffort e : {PngEffort::kFast, PngEffort::kCompact}) {
    const fs::path p = dir_ / "d.png";
    ASSERT_TRUE(write_image(p, img, e));
    auto back = read_image_u16(p);
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(back->width, 37);
    EXPECT_EQ(back->height, 23);
    EXPECT_EQ(back->channels, 1);
    EXPECT_EQ(back->data, img.data);
  }
}

TEST_F(ImageIo, EightBitPngReadAsSixteenThroughOpenImageIo) {
  ImageU8 img(5, 4, 1);
  for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = uint8_t(13 * i);
  const fs::path p = dir_ / "g8.png";
  ASSERT_TRUE(write_image(p, img));
  auto back = read_image_u16(p);
  ASSERT_TRUE(back) << back.error().message;
  for (size_t i = 0; i < img.data.size(); ++i) EXPECT_EQ(back->data[i], img.data[i] * 257);
}

TEST_F(ImageIo, BrokenDepthPngIsAClearError) {
  const fs::path p = dir_ / "d.png";
  ASSERT_TRUE(write_image(p, ramp(64, 48)));
  const std::string good = bytes(p);
  // Cut short.
  put(p, good.substr(0, good.size() / 2));
  auto cut = read_image_u16(p);
  ASSERT_FALSE(cut);
  EXPECT_NE(cut.error().message.find("truncated or corrupt"), std::string::npos) << cut.error().message;
  // A byte of the pixel data changed: the chunk's CRC catches it.
  std::string flipped = good;
  const size_t idat = good.find("IDAT");
  ASSERT_NE(idat, std::string::npos);
  flipped[idat + 10] = char(flipped[idat + 10] ^ 0x5a);
  put(p, flipped);
  auto bad = read_image_u16(p);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("d.png"), std::string::npos);
  // A header claiming 100,000 pixels a side (CRC made to match) is refused before any allocation.
  std::string huge = good;
  const size_t ihdr = good.find("IHDR");
  for (int k = 0; k < 4; ++k) huge[ihdr + 4 + size_t(k)] = "\x00\x01\x86\xa0"[k];
  const uLong crc = crc32(0, reinterpret_cast<const Bytef*>(huge.data() + ihdr), 17);
  for (int k = 0; k < 4; ++k) huge[ihdr + 17 + size_t(k)] = char(crc >> (24 - 8 * k));
  put(p, huge);
  auto big = read_image_u16(p);
  ASSERT_FALSE(big);
  EXPECT_NE(big.error().message.find("IHDR"), std::string::npos) << big.error().message;
  // Not an image at all, and no file.
  put(p, "not a png");
  EXPECT_FALSE(read_image_u16(p));
  EXPECT_FALSE(read_image_u16(dir_ / "missing.png"));
}

}  // namespace
}  // namespace s2r
