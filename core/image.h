// A plain interleaved image. Kept free of OpenCV/OIIO headers on purpose so
// that every stage can pass images around without heavy includes.
#pragma once

#include <cassert>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace s2r {

template <class T>
struct Image {
  int width = 0;
  int height = 0;
  int channels = 0;
  std::vector<T> data;

  Image() = default;
  Image(int w, int h, int c, T fill = T{})
      : width(w), height(h), channels(c), data(static_cast<size_t>(w) * h * c, fill) {}

  bool empty() const { return data.empty(); }
  size_t pixels() const { return static_cast<size_t>(width) * height; }
  T& at(int x, int y, int c = 0) {
    assert(x >= 0 && y >= 0 && x < width && y < height && c >= 0 && c < channels);
    return data[(static_cast<size_t>(y) * width + x) * channels + c];
  }
  const T& at(int x, int y, int c = 0) const {
    assert(x >= 0 && y >= 0 && x < width && y < height && c >= 0 && c < channels);
    return data[(static_cast<size_t>(y) * width + x) * channels + c];
  }
  bool same_shape(const Image& o) const {
    return width == o.width && height == o.height && channels == o.channels;
  }
};

using ImageU8 = Image<uint8_t>;
using ImageU16 = Image<uint16_t>;
using ImageF = Image<float>;

}  // namespace s2r
