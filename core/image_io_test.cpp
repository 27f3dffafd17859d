// Depth PNGs: 16-bit greyscale files are read through libpng directly, any
// other image through OpenImageIO; both give the values written, and a bad
// file gives a readable error.
#include "core/image_io.h"

#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

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
