// One of the few translation units of calibrate/ that include Ceres.
#include "calibrate/turntable_axis.h"
#include "core/angles.h"
#include "calibrate/axis_cost.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>

#include <cmath>
#include <numbers>

namespace s2r {

namespace {


// Holds p's free component along d (the axis has no preferred point along itself).
struct AxisPointPrior {
  explicit AxisPointPrior(const Eigen::Vector3d& p0) : p0_(p0) {}
  template <class T>
  bool operator()(const T* d, const T* p, T* r) const {
    r[0] = T(1e3) * (d[0] * (p[0] - T(p0_.x())) + d[1] * (p[1] - T(p0_.y())) + d[2] * (p[2] - T(p0_.z())));
    return true;
  }
  Eigen::Vector3d p0_;
};

Eigen::Isometry3d pnp(const BoardDetection& d, const Intrinsics& K, bool* ok) {
  std::vector<cv::Point3f> obj;
  std::vector<cv::Point2f> img;
  for (const auto& p : d.board_points) obj.emplace_back(p.x(), p.y(), p.z());
  for (const auto& p : d.image_points) img.emplace_back(p.x(), p.y());
  cv::Mat Km = (cv::Mat_<double>(3, 3) << K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1);
  cv::Mat D = (cv::Mat_<double>(1, 5) << K.dist[0], K.dist[1], K.dist[2], K.dist[3], K.dist[4]);
  cv::Mat rv, tv;
  *ok = cv::solvePnP(obj, img, Km, D, rv, tv, false, cv::SOLVEPNP_IPPE);
  cv::Mat R;
  cv::Rodrigues(rv, R);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) t.linear()(i, j) = R.at<double>(i, j);
    t.translation()[i] = tv.at<double>(i);
  }
  *ok = *ok && t.matrix().allFinite() && t.translation().z() > 0;
  return t;
}

// The board cannot turn upside down on a table: a detection whose board x axis
// points left in the image was numbered from the other end; renumber it.
void orient(BoardDetection& d, const Intrinsics& K) {
  bool ok = false;
  const Eigen::Isometry3d t = pnp(d, K, &ok);
  if (ok && t.linear()(0, 0) < 0) {
    std::reverse(d.image_points.begin(), d.image_points.end());
  }
}

// Least-squares point on an axis from pairs (R, t0 -> t): t = R t0 + (I - R) p.
Eigen::Vector3d axis_point(const std::vector<Eigen::Matrix3d>& R, const std::vector<Eigen::Vector3d>& t0,
                           const std::vector<Eigen::Vector3d>& t, const Eigen::Vector3d& d) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < R.size(); ++i) {
    const Eigen::Matrix3d M = Eigen::Matrix3d::Identity() - R[i];
    A += M.transpose() * M;
    b += M.transpose() * (t[i] - R[i] * t0[i]);
  }
  A += d * d.transpose();  // pin the free component along d to 0
  return A.ldlt().solve(b);
}

}  // namespace

Result<AxisResult> calibrate_turntable_axis(const std::vector<AxisView>& views_in, const Intrinsics& K,
                                            const AxisOptions& o) {
  Stopwatch clock;
  AxisResult out;
  Report& rep = out.report;
  rep.stage = "calibrate.axis";
  if (auto st = K.validate("intrinsics"); !st) return std::unexpected(st.error());
  std::vector<AxisView> views;
  std::vector<Eigen::Isometry3d> poses;
  for (const auto& v : views_in) {
    if (!v.detection.found || v.detection.image_points.size() < 6) {
      rep.skipped["view_without_board"] += 1;
      rep.warnings.push_back("no board in " + v.name + " (table angle " + std::to_string(v.commanded_deg) + "): skipped");
      continue;
    }
    AxisView w = v;
    orient(w.detection, K);
    bool ok = false;
    Eigen::Isometry3d t = pnp(w.detection, K, &ok);
    if (!ok) {
      rep.skipped["view_pnp_failed"] += 1;
      continue;
    }
    views.push_back(std::move(w));
    poses.push_back(t);
  }
  if (views.size() < 3) return fail("the axis needs the board at 3 or more table angles; got " + std::to_string(views.size()));

  // Initial axis direction: rotation axes of the poses relative to the first,
  // signed so the rotation has the commanded sense.
  Eigen::Vector3d dsum = Eigen::Vector3d::Zero();
  std::vector<Eigen::Matrix3d> Rrel;
  std::vector<Eigen::Vector3d> t0s, ts;
  for (size_t i = 1; i < views.size(); ++i) {
    const Eigen::Matrix3d R = poses[i].linear() * poses[0].linear().transpose();
    Eigen::AngleAxisd aa(R);
    const double commanded = (views[i].commanded_deg - views[0].commanded_deg) * kDeg;
    if (aa.angle() < 1e-3) continue;
    Eigen::Vector3d axis = aa.axis();
    if (std::sin(commanded) < 0) axis = -axis;  // AngleAxis angles are in [0, pi]
    dsum += axis * std::min(aa.angle(), 1.0);
    Rrel.push_back(R);
    t0s.push_back(poses[0].translation());
    ts.push_back(poses[i].translation());
  }
  if (dsum.norm() < 1e-9) return fail("the board did not turn between views: no axis can be fitted");
  const Eigen::Vector3d d_init = dsum.normalized();
  double d[3] = {d_init.x(), d_init.y(), d_init.z()};
  const Eigen::Vector3d p_init = axis_point(Rrel, t0s, ts, dsum.normalized());
  out.initial_direction = d_init;
  out.initial_point = p_init - d_init * d_init.dot(p_init);
  double p[3] = {p_init.x(), p_init.y(), p_init.z()};
  Eigen::Quaterniond q0(poses[0].linear());
  double q[4] = {q0.x(), q0.y(), q0.z(), q0.w()};
  double t[3] = {poses[0].translation().x(), poses[0].translation().y(), poses[0].translation().z()};
  std::vector<double> phi(views.size());
  for (size_t i = 0; i < views.size(); ++i) phi[i] = (views[i].commanded_deg - views[0].commanded_deg) * kDeg;

  ceres::Problem problem;
  size_t residuals = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const auto& det = views[i].detection;
    for (size_t k = 0; k < det.image_points.size(); ++k) {
      auto* cost = new ceres::AutoDiffCostFunction<AxisReprojection, 2, 3, 3, 4, 3, 1>(
          new AxisReprojection(det.image_points[k].cast<double>(), det.board_points[k].cast<double>(), K));
      problem.AddResidualBlock(cost, new ceres::HuberLoss(o.huber_px), d, p, q, t, &phi[i]);
      ++residuals;
    }
  }
  problem.AddResidualBlock(new ceres::AutoDiffCostFunction<AxisPointPrior, 1, 3, 3>(new AxisPointPrior(p_init)),
                           nullptr, d, p);
  problem.SetManifold(d, new ceres::SphereManifold<3>());
  problem.SetManifold(q, new ceres::EigenQuaternionManifold());
  problem.SetParameterBlockConstant(&phi[0]);  // the first view defines angle 0
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = 200;
  so.function_tolerance = 1e-14;
  so.parameter_tolerance = 1e-14;
  so.gradient_tolerance = 1e-14;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (!summary.IsSolutionUsable()) return fail("axis fit failed: " + summary.message);

  out.axis.direction_camera = Eigen::Vector3d(d[0], d[1], d[2]).normalized();
  out.axis.point_camera = Eigen::Vector3d(p[0], p[1], p[2]);
  // Report the point on the axis closest to the camera centre (a canonical choice).
  out.axis.point_camera -= out.axis.direction_camera * out.axis.direction_camera.dot(out.axis.point_camera);
  double sq = 0;
  size_t n = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const auto& det = views[i].detection;
    for (size_t k = 0; k < det.image_points.size(); ++k) {
      AxisReprojection f(det.image_points[k].cast<double>(), det.board_points[k].cast<double>(), K);
      double r[2];
      if (f(d, p, q, t, &phi[i], r)) {
        sq += r[0] * r[0] + r[1] * r[1];
        n += 2;
      }
    }
  }
  out.rms_px = n ? std::sqrt(sq / double(n)) : 0;
  out.axis.rms_m = 0;
  double worst_step = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const double measured = views[0].commanded_deg + phi[i] / kDeg;
    out.axis.step_angles_deg.push_back(measured);
    out.commanded_deg.push_back(views[i].commanded_deg);
    out.used.push_back(views[i].name);
    const double e = measured - views[i].commanded_deg;
    worst_step = std::max(worst_step, std::abs(e));
    if (std::abs(e) > o.warn_step_error_deg)
      rep.warnings.push_back(views[i].name + ": the table turned " + std::to_string(measured) + " deg, commanded " +
                             std::to_string(views[i].commanded_deg) + " (error " + std::to_string(e) + " deg)");
  }
  Eigen::Quaterniond qf(q[3], q[0], q[1], q[2]);
  out.camera_from_board0.linear() = qf.normalized().toRotationMatrix();
  out.camera_from_board0.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
  // An axis nearly along the optical axis turns the board in the image plane:
  // the angles stay well defined, the axis point along the view less so.
  const double view_angle = std::acos(std::min(1.0, std::abs(out.axis.direction_camera.z()))) / kDeg;
  if (view_angle < 10)
    rep.warnings.push_back("axis within " + std::to_string(view_angle) +
                           " deg of the optical axis: the axis point is poorly determined along the view");
  rep.errors["rms_px"] = out.rms_px;
  rep.errors["max_step_error_deg"] = worst_step;
  rep.errors["axis_to_optical_axis_deg"] = view_angle;
  rep.counts["views_used"] = double(views.size());
  rep.counts["residuals"] = double(residuals);
  rep.counts["iterations"] = double(summary.iterations.size());
  rep.seconds = clock.seconds();
  if (!out.axis.direction_camera.allFinite() || !out.axis.point_camera.allFinite() || !std::isfinite(out.rms_px))
    return fail("axis fit diverged (non-finite result)");
  return out;
}

Result<PoseAxisFit> fit_axis_to_poses(const std::vector<Eigen::Isometry3d>& w) {
  if (w.size() < 3) return fail("an axis through camera poses needs at least 3 poses");
  std::vector<Eigen::Matrix3d> R;
  std::vector<Eigen::Vector3d> t0, t;
  Eigen::Vector3d dsum = Eigen::Vector3d::Zero();
  for (size_t i = 1; i < w.size(); ++i) {
    // world_from_camera_i = A_i * world_from_camera_0 with A_i a rotation about the axis.
    const Eigen::Matrix3d A = w[i].linear() * w[0].linear().transpose();
    Eigen::AngleAxisd aa(A);
    if (aa.angle() < 1e-6) continue;
    Eigen::Vector3d ax = aa.axis();
    if (dsum.norm() > 0 && ax.dot(dsum) < 0) ax = -ax;
    dsum += ax;
    R.push_back(A);
    t0.push_back(w[0].translation());
    t.push_back(w[i].translation());
  }
  if (dsum.norm() < 1e-12) return fail("the poses do not rotate");
  PoseAxisFit f;
  f.direction = dsum.normalized();
  f.point = axis_point(R, t0, t, f.direction);
  // Camera centres: distance from the axis and height along it should be constant.
  std::vector<double> radius, height;
  for (const auto& p : w) {
    const Eigen::Vector3d v = p.translation() - f.point;
    height.push_back(v.dot(f.direction));
    radius.push_back((v - f.direction * height.back()).norm());
  }
  auto mean = [](const std::vector<double>& v) { double s = 0; for (double x : v) s += x; return s / double(v.size()); };
  const double rm = mean(radius), hm = mean(height);
  double sq = 0;
  for (size_t i = 0; i < w.size(); ++i) sq += (radius[i] - rm) * (radius[i] - rm) + (height[i] - hm) * (height[i] - hm);
  f.rms_m = std::sqrt(sq / double(w.size()));
  for (const auto& p : w) {
    const Eigen::Matrix3d A = p.linear() * w[0].linear().transpose();
    Eigen::AngleAxisd aa(A);
    f.angles_deg.push_back((aa.axis().dot(f.direction) < 0 ? -aa.angle() : aa.angle()) / kDeg);
  }
  return f;
}

}  // namespace s2r
