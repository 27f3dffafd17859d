// Whether a silhouette mask has any foreground in a pixel window (the visual
// hull's test of each cell against each view), or only foreground, answered exactly in O(1) for
// the part of the window made of whole 4 x 4 blocks (a summed-area table of
// the blocks' foreground counts) and by reading the mask for the strips at
// the window's edges. A table per pixel would be 4 bytes a pixel, kept for
// every view at once: 9.5 GB for 200 masks of 12 MP; this one is 1/4 byte a
// pixel beside the mask the caller keeps.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "core/image.h"

namespace s2r {

class MaskWindows {
 public:
  static constexpr int kBlock = 4;

  // `mask` (non-zero in its first channel = foreground) must outlive this.
  explicit MaskWindows(const ImageU8& mask)
      : m_(&mask), w_(mask.width), h_(mask.height), bw_((w_ + kBlock - 1) / kBlock), bh_((h_ + kBlock - 1) / kBlock),
        sum_(size_t(bw_ + 1) * size_t(bh_ + 1), 0) {
    std::vector<int32_t> row(size_t(bw_), 0);
    for (int by = 0; by < bh_; ++by) {
      std::fill(row.begin(), row.end(), 0);
      for (int y = by * kBlock; y < std::min(h_, (by + 1) * kBlock); ++y)
        for (int x = 0; x < w_; ++x) row[size_t(x / kBlock)] += at(x, y) != 0;
      int32_t run = 0;
      for (int bx = 0; bx < bw_; ++bx) {
        run += row[size_t(bx)];
        sum_[size_t(by + 1) * size_t(bw_ + 1) + size_t(bx + 1)] = sum_[size_t(by) * size_t(bw_ + 1) + size_t(bx + 1)] + run;
      }
    }
  }

  // Any foreground in [x0, x1] x [y0, y1] (inclusive, clipped to the image).
  bool any(int x0, int y0, int x1, int y1) const {
    x0 = std::max(x0, 0), y0 = std::max(y0, 0), x1 = std::min(x1, w_ - 1), y1 = std::min(y1, h_ - 1);
    return x0 <= x1 && y0 <= y1 && holds(true, x0, y0, x1, y1);
  }

  // Foreground everywhere in [x0, x1] x [y0, y1], a window wholly inside
  // the image (false for one that is not).
  bool all(int x0, int y0, int x1, int y1) const {
    if (x0 < 0 || y0 < 0 || x1 >= w_ || y1 >= h_ || x0 > x1 || y0 > y1) return false;
    return !holds(false, x0, y0, x1, y1);
  }

  size_t bytes() const { return sum_.size() * sizeof(int32_t); }

 private:
  uint8_t at(int x, int y) const { return m_->data[(size_t(y) * size_t(w_) + size_t(x)) * size_t(m_->channels)]; }
  int32_t blocks(int bx0, int by0, int bx1, int by1) const {
    auto s = [&](int bx, int by) { return sum_[size_t(by) * size_t(bw_ + 1) + size_t(bx)]; };
    return s(bx1 + 1, by1 + 1) - s(bx0, by1 + 1) - s(bx1 + 1, by0) + s(bx0, by0);
  }
  // Whether a pixel of the window (inside the image) is foreground (`fg`)
  // or background (!fg): the whole blocks inside it from the table, the
  // strips at its edges read.
  bool holds(bool fg, int x0, int y0, int x1, int y1) const {
    auto scan = [&](int ax, int ay, int bx, int by) {
      for (int y = ay; y <= by; ++y)
        for (int x = ax; x <= bx; ++x)
          if ((at(x, y) != 0) == fg) return true;
      return false;
    };
    const int bx0 = (x0 + kBlock - 1) / kBlock, by0 = (y0 + kBlock - 1) / kBlock;
    const int bx1 = (x1 + 1) / kBlock - 1, by1 = (y1 + 1) / kBlock - 1;
    if (bx0 > bx1 || by0 > by1) return scan(x0, y0, x1, y1);
    const int32_t count = blocks(bx0, by0, bx1, by1);
    if (fg ? count > 0 : count < (bx1 - bx0 + 1) * (by1 - by0 + 1) * kBlock * kBlock) return true;
    const int ix0 = bx0 * kBlock, iy0 = by0 * kBlock, ix1 = (bx1 + 1) * kBlock - 1, iy1 = (by1 + 1) * kBlock - 1;
    return scan(x0, y0, x1, iy0 - 1) || scan(x0, iy1 + 1, x1, y1) || scan(x0, iy0, ix0 - 1, iy1) || scan(ix1 + 1, iy0, x1, iy1);
  }

  const ImageU8* m_;
  int w_, h_, bw_, bh_;
  std::vector<int32_t> sum_;  // (bw + 1) x (bh + 1): foreground in the blocks above and left
};

}  // namespace s2r
