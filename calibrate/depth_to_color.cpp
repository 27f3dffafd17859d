#include "calibrate/depth_to_color.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>

#include <cmath>

namespace s2r {

namespace {

// Signed distance of a depth point, moved into the colour frame, from a plane n.x = c.
struct PointToPlane {
  PointToPlane(const Eigen::Vector3d& p, const Eigen::Vector3d& n, double c) : p_(p), n_(n), c_(c) {}
  template <class T>
  bool operator()(const T* aa, const T* t, T* r) const {
    const T p[3] = {T(p_.x()), T(p_.y()), T(p_.z())};
    T q[3];
    ceres::AngleAxisRotatePoint(aa, p, q);
    r[0] = T(n_.x()) * (q[0] + t[0]) + T(n_.y()) * (q[1] + t[1]) + T(n_.z()) * (q[2] + t[2]) - T(c_);
    return true;
  }
  Eigen::Vector3d p_, n_;
  double c_;
};

bool inside_convex(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& x) {
  int sign = 0;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Eigen::Vector2d a = poly[i], b = poly[(i + 1) % poly.size()];
    const double c = (b - a).x() * (x - a).y() - (b - a).y() * (x - a).x();
    const int s = c > 0 ? 1 : c < 0 ? -1 : 0;
    if (s != 0) {
      if (sign != 0 && s != sign) return false;
      sign = s;
    }
  }
  return true;
}

}  // namespace

Result<DepthColorResult> calibrate_depth_to_color(const std::vector<DepthColorView>& views, const Intrinsics& Kc,
                                                  const Intrinsics& Kd, double unit, const Eigen::Isometry3d& init) {
  Stopwatch clock;
  DepthColorResult out;
  Report& rep = out.report;
  rep.stage = "calibrate.depth_to_color";
  // Board planes in the colour frame (n.x = c) and the board's inner quadrilateral.
  struct Plane {
    Eigen::Vector3d n;
    double c;
    std::vector<Eigen::Vector3d> quad;  // colour frame, shrunk towards the centre
    size_t view;
  };
  std::vector<Plane> planes;
  cv::Mat K = (cv::Mat_<double>(3, 3) << Kc.fx, 0, Kc.cx, 0, Kc.fy, Kc.cy, 0, 0, 1);
  cv::Mat D = (cv::Mat_<double>(1, 5) << Kc.dist[0], Kc.dist[1], Kc.dist[2], Kc.dist[3], Kc.dist[4]);
  for (size_t v = 0; v < views.size(); ++v) {
    const auto& det = views[v].color_detection;
    if (!det.found || det.image_points.size() < 6) {
      rep.skipped["view_without_board"] += 1;
      continue;
    }
    if (views[v].depth.empty()) {
      rep.skipped["view_without_depth"] += 1;
      continue;
    }
    std::vector<cv::Point3f> obj;
    std::vector<cv::Point2f> img;
    for (const auto& p : det.board_points) obj.emplace_back(p.x(), p.y(), p.z());
    for (const auto& p : det.image_points) img.emplace_back(p.x(), p.y());
    cv::Mat rv, tv, R;
    if (!cv::solvePnP(obj, img, K, D, rv, tv, false, cv::SOLVEPNP_IPPE)) continue;
    cv::Rodrigues(rv, R);
    Eigen::Matrix3d Re;
    Eigen::Vector3d te;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) Re(i, j) = R.at<double>(i, j);
      te[i] = tv.at<double>(i);
    }
    Plane pl;
    pl.n = Re.col(2);
    pl.c = pl.n.dot(te);
    Eigen::Vector3d lo = det.board_points.front().cast<double>(), hi = lo;
    for (const auto& p : det.board_points) {
      lo = lo.cwiseMin(p.cast<double>());
      hi = hi.cwiseMax(p.cast<double>());
    }
    const Eigen::Vector3d mid = 0.5 * (lo + hi), half = 0.35 * (hi - lo);  // 70 % of the inner area
    for (const Eigen::Vector3d& c : {Eigen::Vector3d(-1, -1, 0), Eigen::Vector3d(1, -1, 0), Eigen::Vector3d(1, 1, 0),
                                     Eigen::Vector3d(-1, 1, 0)})
      pl.quad.push_back(Re * (mid + half.cwiseProduct(c)) + te);
    pl.view = v;
    planes.push_back(pl);
  }
  if (planes.size() < 3)
    return fail("depth-to-colour needs the board in 3 or more views with depth; got " + std::to_string(planes.size()));

  Eigen::Isometry3d est = init;
  double aa[3], t[3];
  for (int round = 0; round < 2; ++round) {
    ceres::Problem problem;
    const Eigen::AngleAxisd a0(est.linear());
    for (int i = 0; i < 3; ++i) {
      aa[i] = a0.axis()[i] * a0.angle();
      t[i] = est.translation()[i];
    }
    out.points = 0;
    const Eigen::Isometry3d depth_from_color = est.inverse();
    for (const auto& pl : planes) {
      std::vector<Eigen::Vector2d> poly;
      bool ok = true;
      for (const auto& q : pl.quad) {
        auto px = Kd.project(depth_from_color * q);
        if (!px) ok = false;
        else poly.push_back(*px);
      }
      if (!ok) continue;
      const auto& depth = views[pl.view].depth;
      Eigen::AlignedBox2d box;
      for (const auto& p : poly) box.extend(p);
      const int x0 = std::max(0, int(box.min().x())), x1 = std::min(depth.width - 1, int(box.max().x()));
      const int y0 = std::max(0, int(box.min().y())), y1 = std::min(depth.height - 1, int(box.max().y()));
      for (int y = y0; y <= y1; y += 2)
        for (int x = x0; x <= x1; x += 2) {
          const uint16_t d = depth.at(x, y);
          if (d == 0 || !inside_convex(poly, {double(x), double(y)})) continue;
          auto p = Kd.unproject({double(x), double(y)}, d * unit);
          if (!p) continue;
          problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PointToPlane, 1, 3, 3>(new PointToPlane(*p, pl.n, pl.c)),
                                   new ceres::HuberLoss(0.005), aa, t);
          ++out.points;
        }
    }
    if (out.points < 100) return fail("too few depth points on the board (" + std::to_string(out.points) + ")");
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_QR;
    so.max_num_iterations = 100;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    if (!summary.IsSolutionUsable()) return fail("depth-to-colour fit failed: " + summary.message);
    Eigen::Vector3d w(aa[0], aa[1], aa[2]);
    est = Eigen::Isometry3d::Identity();
    if (w.norm() > 0) est.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
    est.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
    double sq = 0;
    problem.Evaluate(ceres::Problem::EvaluateOptions(), nullptr, nullptr, nullptr, nullptr);
    std::vector<double> res;
    ceres::Problem::EvaluateOptions eo;
    eo.apply_loss_function = false;
    problem.Evaluate(eo, nullptr, &res, nullptr, nullptr);
    for (double r : res) sq += r * r;
    out.rms_m = std::sqrt(sq / double(res.size()));
  }
  if (!est.matrix().allFinite() || !std::isfinite(out.rms_m)) return fail("depth-to-colour fit diverged");
  out.color_from_depth = est;
  rep.errors["rms_point_to_plane_mm"] = 1000 * out.rms_m;
  rep.counts["views_used"] = double(planes.size());
  rep.counts["depth_points"] = double(out.points);
  rep.seconds = clock.seconds();
  return out;
}

}  // namespace s2r
