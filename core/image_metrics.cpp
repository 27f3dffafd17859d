#include "core/image_metrics.h"

#include "core/parallel.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <limits>

namespace s2r {

namespace {

Status check_pair(const ImageU8& a, const ImageU8& b, const ImageU8* mask) {
  if (a.empty() || b.empty()) return fail("image metric: empty image");
  if (!a.same_shape(b))
    return fail("image metric: shapes differ (" + std::to_string(a.width) + "x" +
                std::to_string(a.height) + "x" + std::to_string(a.channels) + " vs " +
                std::to_string(b.width) + "x" + std::to_string(b.height) + "x" +
                std::to_string(b.channels) + ")");
  if (mask && (mask->width != a.width || mask->height != a.height || mask->channels != 1))
    return fail("image metric: mask must be single-channel and the images' size");
  return {};
}

cv::Mat as_mat(const ImageU8& im) {
  return cv::Mat(im.height, im.width, CV_MAKETYPE(CV_8U, im.channels),
                 const_cast<uint8_t*>(im.data.data()));
}

}  // namespace

Result<double> psnr(const ImageU8& a, const ImageU8& b, const ImageU8* mask) {
  if (auto st = check_pair(a, b, mask); !st) return std::unexpected(st.error());
  double sse = 0;
  size_t n = 0;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) {
      if (mask && mask->at(x, y) == 0) continue;
      for (int c = 0; c < a.channels; ++c) {
        double d = double(a.at(x, y, c)) - double(b.at(x, y, c));
        sse += d * d;
      }
      n += static_cast<size_t>(a.channels);
    }
  if (n == 0) return fail("image metric: mask selects no pixel");
  double mse = sse / double(n);
  if (mse == 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(255.0 * 255.0 / mse);
}

Result<double> ssim(const ImageU8& a, const ImageU8& b, const ImageU8* mask) {
  if (auto st = check_pair(a, b, mask); !st) return std::unexpected(st.error());
  const double C1 = (0.01 * 255) * (0.01 * 255), C2 = (0.03 * 255) * (0.03 * 255);
  cv::Mat I1, I2;
  as_mat(a).convertTo(I1, CV_64F);
  as_mat(b).convertTo(I2, CV_64F);
  const cv::Size win(11, 11);
  const double sigma = 1.5;
  auto blur = [&](const cv::Mat& m) {
    cv::Mat o;
    cv::GaussianBlur(m, o, win, sigma, sigma, cv::BORDER_REFLECT);
    return o;
  };
  cv::Mat mu1 = blur(I1), mu2 = blur(I2);
  cv::Mat mu1_2 = mu1.mul(mu1), mu2_2 = mu2.mul(mu2), mu1_mu2 = mu1.mul(mu2);
  cv::Mat s1 = blur(I1.mul(I1)) - mu1_2;
  cv::Mat s2 = blur(I2.mul(I2)) - mu2_2;
  cv::Mat s12 = blur(I1.mul(I2)) - mu1_mu2;
  // Scalar::all keeps the constants in every channel (MatExpr + double would not).
  cv::Mat num = (2 * mu1_mu2 + cv::Scalar::all(C1)).mul(2 * s12 + cv::Scalar::all(C2));
  cv::Mat den = (mu1_2 + mu2_2 + cv::Scalar::all(C1)).mul(s1 + s2 + cv::Scalar::all(C2));
  cv::Mat map;
  cv::divide(num, den, map);
  double sum = 0;
  size_t n = 0;
  const int ch = a.channels;
  for (int y = 0; y < a.height; ++y) {
    const double* row = map.ptr<double>(y);
    for (int x = 0; x < a.width; ++x) {
      if (mask && mask->at(x, y) == 0) continue;
      for (int c = 0; c < ch; ++c) sum += row[x * ch + c];
      n += static_cast<size_t>(ch);
    }
  }
  if (n == 0) return fail("image metric: mask selects no pixel");
  return sum / double(n);
}

double ssim_and_gradient(const ImageF& x, const ImageF& y, ImageF* d_dx, int threads) {
  const double C1 = 1e-4, C2 = 9e-4;
  const int type = CV_32FC(x.channels);
  // Headers on the images' own floats (not written through).
  const cv::Mat X(x.height, x.width, type, const_cast<float*>(x.data.data()));
  const cv::Mat Y(y.height, y.width, type, const_cast<float*>(y.data.data()));
  auto blur = [](const cv::Mat& m) {
    cv::Mat o;
    cv::GaussianBlur(m, o, cv::Size(11, 11), 1.5, 1.5, cv::BORDER_CONSTANT);
    return o;
  };
  // The five windowed moments, one filter a task.
  cv::Mat mom[5];
  parallel_for(5, threads, [&](int k) {
    switch (k) {
      case 0: mom[0] = blur(X); break;
      case 1: mom[1] = blur(Y); break;
      case 2: mom[2] = blur(X.mul(X)); break;
      case 3: mom[3] = blur(Y.mul(Y)); break;
      default: mom[4] = blur(X.mul(Y));
    }
  });
  const size_t n = x.data.size();
  cv::Mat a, b, c;
  if (d_dx) a.create(X.size(), type), b.create(X.size(), type), c.create(X.size(), type);
  const float *pmx = mom[0].ptr<float>(), *pmy = mom[1].ptr<float>(), *pxx = mom[2].ptr<float>(),
              *pyy = mom[3].ptr<float>(), *pxy = mom[4].ptr<float>();
  // The map's terms in row bands, each band's sum kept apart and added in
  // order (the same sum whatever the threads).
  const size_t row = size_t(x.width) * size_t(x.channels);
  const int bands = (x.height + 15) / 16;
  std::vector<double> band_sum(size_t(bands), 0.0);
  parallel_for(bands, threads, [&](int band) {
    double sum = 0;
    const size_t lo = size_t(band) * 16 * row, hi = std::min(n, lo + 16 * row);
    for (size_t i = lo; i < hi; ++i) {
      const double ux = pmx[i], uy = pmy[i];
      const double n1 = 2 * ux * uy + C1, n2 = 2 * (pxy[i] - ux * uy) + C2;
      const double d1 = ux * ux + uy * uy + C1, d2 = (pxx[i] - ux * ux) + (pyy[i] - uy * uy) + C2;
      const double S = n1 * n2 / (d1 * d2);
      sum += S;
      if (!d_dx) continue;
      // dS/d(mean x), dS/d(E[x^2]), dS/d(E[xy]), the variances through the raw moments.
      a.ptr<float>()[i] = float(S * (2 * uy / n1 - 2 * uy / n2 - 2 * ux / d1 + 2 * ux / d2));
      b.ptr<float>()[i] = float(-S / d2);
      c.ptr<float>()[i] = float(2 * S / n2);
    }
    band_sum[size_t(band)] = sum;
  });
  double sum = 0;
  for (double s : band_sum) sum += s;
  if (d_dx) {
    cv::Mat g[3];
    parallel_for(3, threads, [&](int k) { g[k] = blur(k == 0 ? a : k == 1 ? b : c); });
    *d_dx = ImageF(x.width, x.height, x.channels);
    const float inv = float(1.0 / double(n));
    const float *pa = g[0].ptr<float>(), *pb = g[1].ptr<float>(), *pc = g[2].ptr<float>();
    parallel_for(bands, threads, [&](int band) {
      const size_t lo = size_t(band) * 16 * row, hi = std::min(n, lo + 16 * row);
      for (size_t i = lo; i < hi; ++i) d_dx->data[i] = inv * (pa[i] + 2 * x.data[i] * pb[i] + y.data[i] * pc[i]);
    });
  }
  return sum / double(n);
}

Result<ImageU8> matte_band(const ImageU8& matte, int band_px) {
  if (matte.empty() || matte.channels != 1) return fail("matte band: the matte must be a non-empty single-channel image");
  if (band_px < 0) return fail("matte band: band_px must be >= 0");
  cv::Mat inside;
  cv::threshold(as_mat(matte), inside, 127, 255, cv::THRESH_BINARY);
  cv::Mat grown, shrunk;  // not headers of `inside`: dilate and erode would write into it
  if (band_px == 0) grown = inside, shrunk = inside;
  else {
    const cv::Mat k = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * band_px + 1, 2 * band_px + 1));
    // Pixels outside the image neither grow nor shrink the object.
    cv::dilate(inside, grown, k, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
    cv::erode(inside, shrunk, k, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(255));
  }
  ImageU8 band(matte.width, matte.height, 1, 0);
  for (int y = 0; y < matte.height; ++y) {
    const uint8_t *g = grown.ptr<uint8_t>(y), *s = shrunk.ptr<uint8_t>(y);
    for (int x = 0; x < matte.width; ++x) {
      const uint8_t m = matte.at(x, y);
      band.at(x, y) = (g[x] != s[x] || (m > 0 && m < 255)) ? 255 : 0;
    }
  }
  return band;
}

Result<MatteError> matte_error(const ImageU8& alpha, const ImageU8& matte, const ImageU8& band) {
  if (alpha.channels != 1 || matte.channels != 1) return fail("matte error: alpha and matte must be single-channel");
  if (auto st = check_pair(alpha, matte, &band); !st) return std::unexpected(st.error());
  double all = 0, edge = 0;
  MatteError e;
  for (size_t i = 0; i < alpha.pixels(); ++i) {
    const double d = std::abs(double(alpha.data[i]) - double(matte.data[i])) / 255.0;
    all += d;
    if (band.data[i]) edge += d, ++e.edge_pixels;
  }
  e.mae = all / double(alpha.pixels());
  e.edge_mae = e.edge_pixels ? edge / double(e.edge_pixels) : 0.0;
  return e;
}

}  // namespace s2r
