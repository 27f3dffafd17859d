#include "capture/pixel_formats.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstring>

namespace s2r {

std::string fourcc_name(uint32_t f) {
  // As v4l2-ctl prints them: bit 31 marks a big-endian variant
  // (v4l2_fourcc_be), seven bits a character; "Y16 -BE".
  const bool big_endian = f & (1u << 31);
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((f >> (8 * i)) & 0x7f);
    s.push_back(c >= 0x20 && c < 0x7f ? c : '.');
  }
  if (big_endian) return s + "-BE";
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

bool is_depth_format(uint32_t f) { return f == kFourccZ16; }

namespace {
// A frame of `height` rows `stride` bytes apart, each at least `row` bytes.
Status check_size(std::string_view data, int height, int stride, int row, const char* what) {
  if (stride <= 0 || height <= 0 || row <= 0) return fail(std::string(what) + ": bad geometry");
  if (stride < row)
    return fail(std::string(what) + ": rows are " + std::to_string(stride) + " bytes apart but hold " +
                std::to_string(row) + " bytes");
  const size_t need = static_cast<size_t>(stride) * static_cast<size_t>(height);
  if (data.size() < need)
    return fail(std::string(what) + " frame is short: " + std::to_string(data.size()) + " bytes, need " +
                std::to_string(need));
  return {};
}
uint8_t clamp8(int v) { return static_cast<uint8_t>(std::clamp(v, 0, 255)); }
}  // namespace

Result<ImageU8> yuyv_to_rgb(std::string_view data, int w, int h, int stride) {
  if (w % 2) return fail("YUYV width must be even");
  if (!stride) stride = 2 * w;
  if (auto st = check_size(data, h, stride, 2 * w, "YUYV"); !st) return std::unexpected(st.error());
  ImageU8 out(w, h, 3);
  for (int y = 0; y < h; ++y) {
    const auto* row = reinterpret_cast<const uint8_t*>(data.data()) + static_cast<size_t>(y) * stride;
    for (int x = 0; x < w; x += 2) {
      const int y0 = row[2 * x] - 16, u = row[2 * x + 1] - 128, y1 = row[2 * x + 2] - 16, v = row[2 * x + 3] - 128;
      for (int k = 0; k < 2; ++k) {
        const int c = 298 * (k ? y1 : y0);
        out.at(x + k, y, 0) = clamp8((c + 409 * v + 128) >> 8);
        out.at(x + k, y, 1) = clamp8((c - 100 * u - 208 * v + 128) >> 8);
        out.at(x + k, y, 2) = clamp8((c + 516 * u + 128) >> 8);
      }
    }
  }
  return out;
}

Result<ImageU8> mjpeg_to_rgb(std::string_view data, int w, int h) {
  if (data.size() < 4 || static_cast<uint8_t>(data[0]) != 0xFF || static_cast<uint8_t>(data[1]) != 0xD8)
    return fail("MJPEG frame does not start with a JPEG marker (" + std::to_string(data.size()) + " bytes)");
  cv::Mat buf(1, static_cast<int>(data.size()), CV_8U, const_cast<char*>(data.data()));
  cv::Mat bgr = cv::imdecode(buf, cv::IMREAD_COLOR);
  if (bgr.empty()) return fail("MJPEG frame could not be decoded (corrupt or truncated)");
  if (bgr.cols != w || bgr.rows != h)
    return fail("MJPEG frame is " + std::to_string(bgr.cols) + "x" + std::to_string(bgr.rows) + ", expected " +
                std::to_string(w) + "x" + std::to_string(h));
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  ImageU8 out(w, h, 3);
  for (int y = 0; y < h; ++y) std::memcpy(&out.at(0, y, 0), rgb.ptr(y), static_cast<size_t>(w) * 3);
  return out;
}

Result<ImageU8> grey_to_rgb(std::string_view data, int w, int h, int stride) {
  if (!stride) stride = w;
  if (auto st = check_size(data, h, stride, w, "GREY"); !st) return std::unexpected(st.error());
  ImageU8 out(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = static_cast<uint8_t>(data[static_cast<size_t>(y) * stride + x]);
  return out;
}

Result<ImageU16> z16_to_depth(std::string_view data, int w, int h, int stride) {
  if (!stride) stride = 2 * w;
  if (auto st = check_size(data, h, stride, 2 * w, "Z16"); !st) return std::unexpected(st.error());
  ImageU16 out(w, h, 1);
  for (int y = 0; y < h; ++y) std::memcpy(&out.at(0, y), data.data() + static_cast<size_t>(y) * stride, static_cast<size_t>(w) * 2);
  return out;
}

std::string rgb_to_yuyv(const ImageU8& rgb) {
  std::string out(static_cast<size_t>(rgb.width) * rgb.height * 2, '\0');
  auto Y = [](int r, int g, int b) { return clamp8(((66 * r + 129 * g + 25 * b + 128) >> 8) + 16); };
  auto U = [](int r, int g, int b) { return clamp8(((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128); };
  auto V = [](int r, int g, int b) { return clamp8(((112 * r - 94 * g - 18 * b + 128) >> 8) + 128); };
  for (int y = 0; y < rgb.height; ++y)
    for (int x = 0; x + 1 < rgb.width; x += 2) {
      const int r0 = rgb.at(x, y, 0), g0 = rgb.at(x, y, 1), b0 = rgb.at(x, y, 2);
      const int r1 = rgb.at(x + 1, y, 0), g1 = rgb.at(x + 1, y, 1), b1 = rgb.at(x + 1, y, 2);
      uint8_t* p = reinterpret_cast<uint8_t*>(out.data()) + (static_cast<size_t>(y) * rgb.width + x) * 2;
      p[0] = Y(r0, g0, b0);
      p[1] = U((r0 + r1) / 2, (g0 + g1) / 2, (b0 + b1) / 2);
      p[2] = Y(r1, g1, b1);
      p[3] = V((r0 + r1) / 2, (g0 + g1) / 2, (b0 + b1) / 2);
    }
  return out;
}

std::string rgb_to_mjpeg(const ImageU8& rgb, int quality) {
  cv::Mat m(rgb.height, rgb.width, CV_8UC3, const_cast<uint8_t*>(rgb.data.data())), bgr;
  cv::cvtColor(m, bgr, cv::COLOR_RGB2BGR);
  std::vector<uint8_t> buf;
  cv::imencode(".jpg", bgr, buf, {cv::IMWRITE_JPEG_QUALITY, quality});
  return std::string(buf.begin(), buf.end());
}

std::string rgb_to_grey(const ImageU8& rgb) {
  std::string out(rgb.pixels(), '\0');
  for (int y = 0; y < rgb.height; ++y)
    for (int x = 0; x < rgb.width; ++x)
      out[static_cast<size_t>(y) * rgb.width + x] =
          static_cast<char>((77 * rgb.at(x, y, 0) + 150 * rgb.at(x, y, 1) + 29 * rgb.at(x, y, 2) + 128) >> 8);
  return out;
}

std::string depth_to_z16(const ImageU16& d) {
  std::string out(d.pixels() * 2, '\0');
  std::memcpy(out.data(), d.data.data(), out.size());
  return out;
}

}  // namespace s2r
