#include "reconstruct/photo_depth.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace s2r {

PhotoDepthStats& PhotoDepthStats::operator+=(const PhotoDepthStats& o) {
  pixels_on_hull += o.pixels_on_hull;
  pixels_untextured += o.pixels_untextured;
  pixels_at_silhouette += o.pixels_at_silhouette;
  pixels_unmatched += o.pixels_unmatched;
  pixels_at_hull += o.pixels_at_hull;
  pixels_behind_hull += o.pixels_behind_hull;
  pixels_ambiguous += o.pixels_ambiguous;
  planes += o.planes;
  shift_sum_m += o.shift_sum_m;
  neighbours_used += o.neighbours_used;
  return *this;
}

namespace {

// Grey 0..1 (Rec. 601 weights), the whole image.
cv::Mat grey_of(const ImageU8& im) {
  cv::Mat g(im.height, im.width, CV_32F);
  const float s = 1.0f / 255.0f;
  for (int y = 0; y < im.height; ++y) {
    float* row = g.ptr<float>(y);
    const uint8_t* src = im.data.data() + size_t(y) * size_t(im.width) * size_t(im.channels);
    for (int x = 0; x < im.width; ++x, src += im.channels)
      row[x] = im.channels >= 3 ? (0.299f * src[0] + 0.587f * src[1] + 0.114f * src[2]) * s : src[0] * s;
  }
  return g;
}

cv::Mat mask_of(const PhotoView& v) {
  if (!v.mask || v.mask->empty()) return cv::Mat(v.K.height, v.K.width, CV_8U, cv::Scalar(255));
  return cv::Mat(v.mask->height, v.mask->width, CV_8U, const_cast<uint8_t*>(v.mask->data.data())).clone();
}

cv::Mat box(const cv::Mat& m, int win) {
  cv::Mat out;
  cv::boxFilter(m, out, CV_32F, cv::Size(win, win), cv::Point(-1, -1), true, cv::BORDER_REPLICATE);
  return out;
}

}  // namespace

std::vector<size_t> photo_neighbours(const std::vector<PhotoView>& views, size_t ref, const Eigen::Vector3d& centre,
                                     const PhotoDepthParams& p) {
  auto dir = [&](size_t i) { return (centre - views[i].world_from_camera.translation()).normalized(); };
  const Eigen::Vector3d d0 = dir(ref);
  std::vector<std::pair<double, size_t>> by_angle;
  for (size_t i = 0; i < views.size(); ++i) {
    if (i == ref) continue;
    const double a = std::acos(std::clamp(d0.dot(dir(i)), -1.0, 1.0)) * 180.0 / std::numbers::pi;
    if (a >= 1.0 && a <= p.max_angle_deg) by_angle.emplace_back(a, i);
  }
  std::sort(by_angle.begin(), by_angle.end());
  std::vector<size_t> out;
  for (size_t k = 0; k < by_angle.size() && int(k) < p.neighbours; ++k) out.push_back(by_angle[k].second);
  return out;
}

ImageF photo_consistent_depth(const std::vector<PhotoView>& views, size_t ref, const std::vector<size_t>& neighbours,
                              const ImageF& hull, const PhotoDepthParams& p, PhotoDepthStats* stats) {
  PhotoDepthStats st;
  const PhotoView& rv = views[ref];
  ImageF out(hull.width, hull.height, 1, 0.0f);
  const int r = p.window / 2, win = 2 * r + 1;
  // The region the hull covers, with the window's margin.
  int x0 = hull.width, y0 = hull.height, x1 = -1, y1 = -1;
  float dmin = std::numeric_limits<float>::max(), dmax = 0;
  for (int y = 0; y < hull.height; ++y)
    for (int x = 0; x < hull.width; ++x) {
      const float d = hull.data[size_t(y) * size_t(hull.width) + size_t(x)];
      if (!(d > 0)) continue;
      ++st.pixels_on_hull;
      x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
      dmin = std::min(dmin, d), dmax = std::max(dmax, d);
    }
  st.neighbours_used = int(neighbours.size());
  if (x1 < 0 || neighbours.size() < 2 || !(p.step_m > 0) || !(p.range_m > 0)) {
    st.pixels_unmatched = st.pixels_on_hull;
    if (stats) *stats += st;
    return out;
  }
  x0 = std::max(0, x0 - r), y0 = std::max(0, y0 - r);
  x1 = std::min(hull.width - 1, x1 + r), y1 = std::min(hull.height - 1, y1 + r);
  const int W = x1 - x0 + 1, H = y1 - y0 + 1;
  const cv::Rect roi(x0, y0, W, H);

  // The reference window's mean and spread.
  const cv::Mat I = grey_of(*rv.color)(roi).clone();
  const cv::Mat mI = box(I, win), mII = box(I.mul(I), win);
  cv::Mat sI(H, W, CV_32F);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      sI.at<float>(y, x) = std::sqrt(std::max(0.0f, mII.at<float>(y, x) - mI.at<float>(y, x) * mI.at<float>(y, x)));

  // Each pixel's unit ray in the world (NaN where the lens gives none).
  const Eigen::Matrix3f R = rv.world_from_camera.linear().cast<float>();
  const Eigen::Vector3f C = rv.world_from_camera.translation().cast<float>();
  std::vector<Eigen::Vector3f> ray(size_t(W) * size_t(H), Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      if (auto d = rv.K.ray({double(x + x0), double(y + y0)})) ray[size_t(y) * size_t(W) + size_t(x)] = R * d->normalized().cast<float>();

  // Which pixels search, over which distances. A
  // window that crosses the silhouette sees the backdrop, which is not at d.
  cv::Mat inside;
  mask_of(rv)(roi).convertTo(inside, CV_32F, 1.0 / 255.0);
  cv::threshold(inside, inside, 0.0, 1.0, cv::THRESH_BINARY);
  inside = box(inside, win);
  cv::Mat lo(H, W, CV_32F, cv::Scalar(0)), hi(H, W, CV_32F, cv::Scalar(-1));
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float d = hull.at(x + x0, y + y0);
      if (!(d > 0)) continue;
      if (inside.at<float>(y, x) < 0.999f) {
        ++st.pixels_at_silhouette;
        continue;
      }
      if (sI.at<float>(y, x) < float(p.min_texture)) {
        ++st.pixels_untextured;
        continue;
      }
      lo.at<float>(y, x) = d, hi.at<float>(y, x) = d + float(p.range_m);
    }

  struct Neighbour {
    cv::Mat grey, mask;
    Eigen::Isometry3f cam_from_world;
    const Intrinsics* K;
  };
  std::vector<Neighbour> nb;
  for (size_t j : neighbours)
    nb.push_back({grey_of(*views[j].color), mask_of(views[j]), views[j].world_from_camera.inverse().cast<float>(), &views[j].K});

  // Tile by tile (32 x 32 pixels and the window's margin), each over the
  // distances its own pixels search: a pixel meets range_m / step
  // hypotheses, not the whole object's depth.
  cv::Mat best(H, W, CV_32F, cv::Scalar(-2)), best_d(H, W, CV_32F, cv::Scalar(0)), at_hull(H, W, CV_32F, cv::Scalar(-2));
  const float step = float(p.step_m);
  const int planes = int(std::ceil((dmax + float(p.range_m) - dmin) / step)) + 1;
  st.planes = size_t(planes);
  constexpr int T = 32;
  cv::Mat mapx, mapy, warped, valid, v, t1, t2, count;
  for (int ty = 0; ty < H; ty += T)
    for (int tx = 0; tx < W; tx += T) {
      const int ix1 = std::min(W, tx + T), iy1 = std::min(H, ty + T);
      float tlo = std::numeric_limits<float>::max(), thi = -1;
      for (int y = ty; y < iy1; ++y)
        for (int x = tx; x < ix1; ++x)
          if (lo.at<float>(y, x) > 0) tlo = std::min(tlo, lo.at<float>(y, x)), thi = std::max(thi, hi.at<float>(y, x));
      if (thi < 0) continue;
      const cv::Rect reg(cv::Point(std::max(0, tx - r), std::max(0, ty - r)), cv::Point(std::min(W, ix1 + r), std::min(H, iy1 + r)));
      const cv::Mat Ir = I(reg), mIr = mI(reg), sIr = sI(reg);
      mapx.create(reg.size(), CV_32F), mapy.create(reg.size(), CV_32F);
      const int k0 = std::max(0, int(std::floor((tlo - step - dmin) / step))),
                k1 = std::min(planes - 1, int(std::ceil((thi - dmin) / step)));
      for (int k = k0; k <= k1; ++k) {
        const float d = dmin + step * float(k);
        t1.create(reg.size(), CV_32F), t2.create(reg.size(), CV_32F), count.create(reg.size(), CV_8U);
        t1.setTo(-2), t2.setTo(-2), count.setTo(0);
        for (const Neighbour& n : nb) {
          for (int y = 0; y < reg.height; ++y)
            for (int x = 0; x < reg.width; ++x) {
              const Eigen::Vector3f& u = ray[size_t(y + reg.y) * size_t(W) + size_t(x + reg.x)];
              float px = -10, py = -10;
              if (u.allFinite()) {
                const Eigen::Vector3f pc = n.cam_from_world * (C + d * u);
                if (auto q = n.K->project(pc.cast<double>())) px = float(q->x()), py = float(q->y());
              }
              mapx.at<float>(y, x) = px, mapy.at<float>(y, x) = py;
            }
          cv::remap(n.grey, warped, mapx, mapy, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
          cv::remap(n.mask, valid, mapx, mapy, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
          valid.convertTo(v, CV_32F, 1.0 / 255.0);
          cv::threshold(v, v, 0.0, 1.0, cv::THRESH_BINARY);
          const cv::Mat mv = box(v, win), mW = box(warped, win), mWW = box(warped.mul(warped), win),
                        mIW = box(Ir.mul(warped), win);
          for (int y = ty; y < iy1; ++y)
            for (int x = tx; x < ix1; ++x) {
              const float l = lo.at<float>(y, x);
              if (!(l > 0) || d < l - step || d > hi.at<float>(y, x)) continue;
              const int ry = y - reg.y, rx = x - reg.x;
              if (mv.at<float>(ry, rx) < 0.999f) continue;  // the window leaves the neighbour's image or silhouette
              const float mw = mW.at<float>(ry, rx);
              const float sw = std::sqrt(std::max(0.0f, mWW.at<float>(ry, rx) - mw * mw));
              if (sw < 0.25f * float(p.min_texture)) continue;  // flat there: no evidence either way
              const float ncc = (mIW.at<float>(ry, rx) - mIr.at<float>(ry, rx) * mw) / (sIr.at<float>(ry, rx) * sw);
              float& a = t1.at<float>(ry, rx);
              float& b = t2.at<float>(ry, rx);
              if (ncc > a) b = a, a = ncc;
              else if (ncc > b) b = ncc;
              ++count.at<uint8_t>(ry, rx);
            }
        }
        for (int y = ty; y < iy1; ++y)
          for (int x = tx; x < ix1; ++x) {
            const int ry = y - reg.y, rx = x - reg.x;
            if (count.at<uint8_t>(ry, rx) < 2) continue;
            const float s = 0.5f * (t1.at<float>(ry, rx) + t2.at<float>(ry, rx));
            float& bs = best.at<float>(y, x);
            if (s > bs) bs = s, best_d.at<float>(y, x) = d;
            if (d <= lo.at<float>(y, x) + step) at_hull.at<float>(y, x) = std::max(at_hull.at<float>(y, x), s);
          }
      }
    }

  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float l = lo.at<float>(y, x);
      if (!(l > 0)) continue;
      const float s = best.at<float>(y, x), d = std::max(best_d.at<float>(y, x), l);
      float& o = out.at(x + x0, y + y0);
      if (s < float(p.min_ncc)) {
        ++st.pixels_unmatched;
      } else if (d <= l + step) {
        ++st.pixels_at_hull;
        o = d;
      } else if (s - at_hull.at<float>(y, x) < float(p.min_gain)) {
        ++st.pixels_ambiguous;
      } else {
        ++st.pixels_behind_hull;
        st.shift_sum_m += double(d - l);
        o = d;
      }
    }
  if (stats) *stats += st;
  return out;
}

}  // namespace s2r
