#include "calibrate/intrinsics.h"

#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <cmath>
#include <numeric>

#include "core/image_io.h"
#include "core/progress.h"

namespace s2r {

namespace {

struct Fit {
  double rms = 0;
  cv::Mat K, D, std_int;
  std::vector<double> per_view;
  std::vector<cv::Mat> rvecs;
};

Fit fit(const std::vector<std::vector<cv::Point3f>>& obj, const std::vector<std::vector<cv::Point2f>>& img,
        cv::Size size, int flags) {
  Fit f;
  f.K = cv::Mat::eye(3, 3, CV_64F);
  f.K.at<double>(0, 2) = (size.width - 1) / 2.0;
  f.K.at<double>(1, 2) = (size.height - 1) / 2.0;
  f.D = cv::Mat::zeros(5, 1, CV_64F);
  std::vector<cv::Mat> tv;
  cv::Mat std_ext, per_view;
  f.rms = cv::calibrateCamera(obj, img, size, f.K, f.D, f.rvecs, tv, f.std_int, std_ext, per_view, flags,
                              cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  for (int i = 0; i < per_view.rows; ++i) f.per_view.push_back(per_view.at<double>(i));
  return f;
}

bool finite(const cv::Mat& m) { return cv::checkRange(m); }

}  // namespace

Result<IntrinsicsResult> calibrate_intrinsics(const std::vector<BoardDetection>& views,
                                              const std::vector<std::string>& names, int width, int height,
                                              const IntrinsicsOptions& o) {
  Stopwatch clock;
  IntrinsicsResult out;
  Report& rep = out.report;
  rep.stage = "calibrate.intrinsics";
  rep.params["board"] = o.board.to_string();
  std::vector<size_t> used;
  for (size_t i = 0; i < views.size(); ++i) {
    ViewResult v;
    v.name = i < names.size() ? names[i] : "view " + std::to_string(i);
    v.detected = views[i].found && views[i].image_points.size() >= 4;
    if (!v.detected) {
      v.note = "board not detected";
      rep.skipped["view_without_board"] += 1;
    } else {
      used.push_back(i);
    }
    out.views.push_back(v);
  }
  if (used.size() < 2)
    return fail("intrinsics need at least 2 views with the board detected; got " + std::to_string(used.size()) +
                " of " + std::to_string(views.size()));
  const cv::Size size(width, height);
  auto collect = [&](const std::vector<size_t>& idx, std::vector<std::vector<cv::Point3f>>& obj,
                     std::vector<std::vector<cv::Point2f>>& img) {
    obj.clear();
    img.clear();
    for (size_t i : idx) {
      std::vector<cv::Point3f> o3;
      std::vector<cv::Point2f> o2;
      for (const auto& p : views[i].board_points) o3.emplace_back(p.x(), p.y(), p.z());
      for (const auto& p : views[i].image_points) o2.emplace_back(p.x(), p.y());
      obj.push_back(o3);
      img.push_back(o2);
    }
  };
  // Few views cannot pin every parameter: fix what they cannot see.
  int flags = o.fix_k3 ? cv::CALIB_FIX_K3 : 0;
  if (static_cast<int>(used.size()) < o.min_views) {
    flags = cv::CALIB_FIX_PRINCIPAL_POINT | cv::CALIB_ZERO_TANGENT_DIST | cv::CALIB_FIX_K2 | cv::CALIB_FIX_K3;
    rep.warnings.push_back("only " + std::to_string(used.size()) +
                           " views: principal point fixed at the centre, only fx, fy and k1 estimated");
  }
  std::vector<std::vector<cv::Point3f>> obj;
  std::vector<std::vector<cv::Point2f>> img;
  collect(used, obj, img);
  Fit f = fit(obj, img, size, flags);
  // Drop views that make the fit worse, one at a time, worst first.
  while (used.size() > static_cast<size_t>(std::max(o.min_views, 3))) {
    std::vector<double> sorted = f.per_view;
    std::sort(sorted.begin(), sorted.end());
    const double median = sorted[sorted.size() / 2];
    const size_t worst = static_cast<size_t>(std::max_element(f.per_view.begin(), f.per_view.end()) - f.per_view.begin());
    if (!(f.per_view[worst] > o.reject_factor * median)) break;
    std::vector<size_t> trial = used;
    trial.erase(trial.begin() + static_cast<long>(worst));
    collect(trial, obj, img);
    Fit g = fit(obj, img, size, flags);
    if (!(g.rms < f.rms)) break;
    ViewResult& v = out.views[used[worst]];
    v.note = "rejected: " + std::to_string(f.per_view[worst]) + " px RMS > " + std::to_string(o.reject_factor) +
             " x median " + std::to_string(median) + " px; fit RMS " + std::to_string(f.rms) + " -> " +
             std::to_string(g.rms) + " px without it";
    v.rms_px = f.per_view[worst];
    rep.skipped["view_rejected"] += 1;
    used = std::move(trial);
    f = g;
  }
  if (!finite(f.K) || !finite(f.D) || !std::isfinite(f.rms))
    return fail("intrinsics fit diverged (non-finite parameters); the views do not constrain the camera");
  for (size_t k = 0; k < used.size(); ++k) {
    out.views[used[k]].used = true;
    out.views[used[k]].rms_px = f.per_view[k];
  }
  Intrinsics K;
  K.width = width;
  K.height = height;
  K.fx = f.K.at<double>(0, 0);
  K.fy = f.K.at<double>(1, 1);
  K.cx = f.K.at<double>(0, 2);
  K.cy = f.K.at<double>(1, 2);
  for (int i = 0; i < 5; ++i) K.dist[size_t(i)] = f.D.at<double>(i);
  if (!(K.fx > 0 && K.fy > 0)) return fail("intrinsics fit gave a non-positive focal length");
  out.calibration = SensorCalibration{K, f.rms, static_cast<int>(used.size())};
  // calibrateCamera's order: fx fy cx cy k1 k2 p1 p2 k3 ...
  for (int i = 0; i < 9 && i < f.std_int.rows; ++i) {
    const double s = f.std_int.at<double>(i);
    out.stddev[size_t(i)] = std::isfinite(s) ? s : 0;
  }
  // Degenerate geometry: boards all nearly parallel confound focal length and
  // distance (a perfect fit with a wrong fx), so look at the board normals.
  double max_tilt_deg = 0;
  for (size_t i = 0; i < f.rvecs.size(); ++i)
    for (size_t j = i + 1; j < f.rvecs.size(); ++j) {
      cv::Mat Ri, Rj;
      cv::Rodrigues(f.rvecs[i], Ri);
      cv::Rodrigues(f.rvecs[j], Rj);
      const double c = std::clamp(Ri.col(2).dot(Rj.col(2)), -1.0, 1.0);
      max_tilt_deg = std::max(max_tilt_deg, std::acos(c) * 180 / M_PI);
    }
  rep.errors["board_normal_spread_deg"] = max_tilt_deg;
  if (max_tilt_deg < 10)
    rep.warnings.push_back("boards nearly parallel (normals within " + std::to_string(max_tilt_deg) +
                           " deg): focal length and distance are confounded; tilt the board in different directions");
  // Weak data also shows as a focal length the data barely constrain.
  const double rel = out.stddev[0] / K.fx;
  if (rel > 0.01)
    rep.warnings.push_back("focal length poorly constrained (std " + std::to_string(100 * rel) +
                           " % of fx): add views with the board tilted in different directions");
  rep.errors["rms_px"] = f.rms;
  rep.errors["fx_std_px"] = out.stddev[0];
  rep.errors["fy_std_px"] = out.stddev[1];
  rep.counts["views"] = double(views.size());
  rep.counts["views_used"] = double(used.size());
  rep.params["fx"] = K.fx;
  rep.params["fy"] = K.fy;
  rep.params["cx"] = K.cx;
  rep.params["cy"] = K.cy;
  rep.seconds = clock.seconds();
  return out;
}

Result<IntrinsicsResult> calibrate_intrinsics_from_files(const std::vector<std::filesystem::path>& images,
                                                         const IntrinsicsOptions& o) {
  if (images.empty()) return fail("no images given");
  Stopwatch clock;
  std::vector<BoardDetection> dets;
  std::vector<std::string> names;
  int width = 0, height = 0;
  Progress progress("detect board", images.size());
  for (const auto& p : images) {
    auto im = read_image_u8(p);
    if (!im) return std::unexpected(im.error());
    if (width == 0) {
      width = im->width;
      height = im->height;
    } else if (im->width != width || im->height != height) {
      return fail("'" + p.string() + "' is " + std::to_string(im->width) + "x" + std::to_string(im->height) +
                  ", the first image is " + std::to_string(width) + "x" + std::to_string(height));
    }
    auto d = detect_board(*im, o.board);
    if (!d) return std::unexpected(d.error());
    dets.push_back(std::move(*d));
    names.push_back(p.filename().string());
    progress.tick();
  }
  progress.done();
  auto r = calibrate_intrinsics(dets, names, width, height, o);
  if (r) r->report.seconds = clock.seconds();
  return r;
}

}  // namespace s2r
