#include "reconstruct/backdrop_plate.h"

#include <opencv2/core.hpp>
#include <opencv2/photo.hpp>

#include <algorithm>
#include <cmath>

#include "core/parallel.h"
#include "core/progress.h"

namespace s2r {

namespace {

// `mask` eroded by a square of half-width r: non-zero only where every pixel
// within r (inside the image) was non-zero (two passes of a running count).
ImageU8 erode(const ImageU8& mask, int r) {
  const int W = mask.width, H = mask.height;
  ImageU8 rows(W, H, 1), out(W, H, 1);
  for (int y = 0; y < H; ++y) {
    int run = 0;  // zeros in the window
    for (int x = -r; x < W; ++x) {
      if (x + r < W) run += mask.at(x + r, y) == 0;
      if (x - r - 1 >= 0) run -= mask.at(x - r - 1, y) == 0;
      if (x >= 0) rows.at(x, y) = run == 0 ? 255 : 0;
    }
  }
  for (int x = 0; x < W; ++x) {
    int run = 0;
    for (int y = -r; y < H; ++y) {
      if (y + r < H) run += rows.at(x, y + r) == 0;
      if (y - r - 1 >= 0) run -= rows.at(x, y - r - 1) == 0;
      if (y >= 0) out.at(x, y) = run == 0 ? 255 : 0;
    }
  }
  return out;
}

}  // namespace

BackdropPlateResult make_backdrop_plate(const std::vector<const ImageU8*>& photos, const std::vector<ImageU8>& empty,
                                        const std::array<float, 3>& background, const BackdropPlateOptions& o) {
  BackdropPlateResult res;
  if (photos.empty() || photos.size() != empty.size()) {
    res.skipped = "no_backdrop_pixels";
    return res;
  }
  const int W = photos[0]->width, H = photos[0]->height;
  for (size_t i = 0; i < photos.size(); ++i)
    if (photos[i]->width != W || photos[i]->height != H || empty[i].width != W || empty[i].height != H) {
      res.skipped = "views_differ_in_size";
      return res;
    }
  std::vector<ImageU8> backdrop(photos.size());
  parallel_for(int(photos.size()), 0, [&](int i) { backdrop[size_t(i)] = erode(empty[size_t(i)], o.margin_px); });
  const size_t need = std::max<size_t>(3, size_t(std::ceil(o.min_share * double(photos.size()))));
  ImageU8 plate(W, H, 3);
  std::vector<float> spread(size_t(W) * H, -1.f);  // per kept pixel: the largest channel's MAD
  SharedProgress rows("backdrop plate", size_t(H));
  parallel_for(H, 0, [&](int y) {
    rows.tick();
    std::vector<uint8_t> s[3];
    std::vector<int> dev;
    for (int x = 0; x < W; ++x) {
      for (auto& v : s) v.clear();
      for (size_t i = 0; i < photos.size(); ++i)
        if (backdrop[i].at(x, y)) {
          const ImageU8& p = *photos[i];
          for (int c = 0; c < 3; ++c) s[c].push_back(p.at(x, y, std::min(c, p.channels - 1)));
        }
      if (s[0].size() < need) {
        for (int c = 0; c < 3; ++c) plate.at(x, y, c) = uint8_t(std::lround(std::clamp(background[size_t(c)], 0.f, 1.f) * 255.f));
        continue;
      }
      float worst = 0;
      for (int c = 0; c < 3; ++c) {
        auto mid = s[c].begin() + std::ptrdiff_t(s[c].size() / 2);
        std::nth_element(s[c].begin(), mid, s[c].end());
        const int med = *mid;
        plate.at(x, y, c) = uint8_t(med);
        dev.clear();
        for (uint8_t v : s[c]) dev.push_back(std::abs(int(v) - med));
        auto dmid = dev.begin() + std::ptrdiff_t(dev.size() / 2);
        std::nth_element(dev.begin(), dmid, dev.end());
        worst = std::max(worst, float(*dmid));
      }
      spread[size_t(y) * W + size_t(x)] = worst;
    }
  });
  rows.done();
  std::vector<float> kept;
  size_t uniform = 0;
  for (size_t p = 0; p < spread.size(); ++p) {
    if (spread[p] < 0) continue;
    kept.push_back(spread[p]);
    bool near = true;
    for (int c = 0; c < 3; ++c)
      near = near && std::abs(float(plate.data[p * 3 + size_t(c)]) - background[size_t(c)] * 255.f) <= float(o.uniform_tolerance);
    uniform += near;
  }
  res.kept_share = double(kept.size()) / double(spread.size());
  if (kept.empty()) {
    res.skipped = "no_backdrop_pixels";
    return res;
  }
  auto mid = kept.begin() + std::ptrdiff_t(kept.size() / 2);
  std::nth_element(kept.begin(), mid, kept.end());
  res.spread = *mid;
  if (res.spread > o.max_spread) {
    res.skipped = "not_static";
    return res;
  }
  if (double(uniform) >= o.uniform_share * double(kept.size())) {
    res.skipped = "uniform";
    return res;
  }
  // The holes: filled from the kept plate around them, not left one colour
  // (a held-out view that sees past the object's edge where the training
  // photos never did shows the wall there, not a band of background).
  cv::Mat holes(H, W, CV_8U, cv::Scalar(0));
  size_t filled = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      if (spread[size_t(y) * W + size_t(x)] < 0) holes.at<uint8_t>(y, x) = 255, ++filled;
  if (filled) {
    cv::Mat in(H, W, CV_8UC3, plate.data.data()), out;
    cv::inpaint(in, holes, out, o.fill_radius_px, cv::INPAINT_TELEA);
    out.copyTo(in);  // in is a header of plate's pixels
  }
  res.filled_share = double(filled) / double(spread.size());
  res.plate = std::move(plate);
  return res;
}

}  // namespace s2r
