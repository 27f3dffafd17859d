// Turntable axis and table angles from dot markers (calibrate/table_markers.h).
// OpenCV finds the dots, PCL's RANSAC the table plane, Ceres the joint fit.
#include "calibrate/table_markers.h"
#include "core/angles.h"

#include <ceres/ceres.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/ransac.h>
#include <pcl/sample_consensus/sac_model_plane.h>
#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "capture/session.h"
#include "core/parallel.h"

namespace s2r {

namespace {


struct Dot {
  Eigen::Vector2d pixel;
  std::optional<Eigen::Vector3d> depth_point;  // from the depth image, camera frame
};

// Bright round blobs on a dark surround, with the median depth around each.
std::vector<Dot> find_dots(const ImageU8& color, const ImageU16& depth, double unit, const Intrinsics& K,
                           const MarkerOptions& o) {
  cv::Mat rgb(color.height, color.width, color.channels == 4 ? CV_8UC4 : CV_8UC3, const_cast<uint8_t*>(color.data.data()));
  cv::Mat grey;
  cv::cvtColor(rgb, grey, color.channels == 4 ? cv::COLOR_RGBA2GRAY : cv::COLOR_RGB2GRAY);
  cv::SimpleBlobDetector::Params p;
  p.filterByColor = true;
  p.blobColor = 255;
  p.minThreshold = 60;
  p.maxThreshold = 250;
  p.thresholdStep = 10;
  p.filterByArea = true;
  p.minArea = float(o.min_area_px);
  p.maxArea = float(o.max_area_px);
  p.filterByCircularity = true;
  p.minCircularity = 0.3f;
  p.filterByInertia = true;
  p.minInertiaRatio = 0.15f;
  p.filterByConvexity = false;
  std::vector<cv::KeyPoint> keys;
  cv::SimpleBlobDetector::create(p)->detect(grey, keys);
  std::vector<Dot> dots;
  for (const auto& k : keys) {
    const int cx = int(std::lround(k.pt.x)), cy = int(std::lround(k.pt.y));
    const int ring = int(std::ceil(k.size)) + 2;
    double sum = 0;
    int n = 0;
    std::vector<double> z;
    for (int dy = -ring; dy <= ring; ++dy)
      for (int dx = -ring; dx <= ring; ++dx) {
        const int x = cx + dx, y = cy + dy;
        if (x < 0 || y < 0 || x >= grey.cols || y >= grey.rows) continue;
        const int r2 = dx * dx + dy * dy;
        if (r2 >= (ring - 1) * (ring - 1) && r2 <= ring * ring) sum += grey.at<uint8_t>(y, x), ++n;
        if (r2 <= ring * ring && !depth.empty()) {
          const uint16_t d = depth.data[size_t(y) * depth.width + x];
          if (d > 0) z.push_back(d * unit);
        }
      }
    if (n == 0 || sum / n > o.dark_surround) continue;
    Dot dot;
    dot.pixel = {k.pt.x, k.pt.y};
    if (z.size() >= 3) {
      std::nth_element(z.begin(), z.begin() + long(z.size() / 2), z.end());
      if (auto ray = K.unproject(dot.pixel, z[z.size() / 2])) dot.depth_point = *ray;
    }
    dots.push_back(dot);
  }
  return dots;
}

// A 2D rigid motion b = R a + t between two frames' dots: the best of a
// two-point RANSAC over pairs of equal length, refined on its inliers.
struct Motion {
  Eigen::Matrix2d R = Eigen::Matrix2d::Identity();
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  std::vector<std::pair<int, int>> matches;
};

Eigen::Matrix2d rot2(double a) {
  Eigen::Matrix2d r;
  r << std::cos(a), -std::sin(a), std::sin(a), std::cos(a);
  return r;
}

std::vector<std::pair<int, int>> inliers_of(const std::vector<Eigen::Vector2d>& A, const std::vector<Eigen::Vector2d>& B,
                                            const Eigen::Matrix2d& R, const Eigen::Vector2d& t, double tol) {
  std::vector<std::pair<int, int>> m;
  std::vector<char> used(B.size(), 0);
  for (size_t i = 0; i < A.size(); ++i) {
    const Eigen::Vector2d x = R * A[i] + t;
    int best = -1;
    double bd = tol * tol;
    for (size_t j = 0; j < B.size(); ++j) {
      const double d = (B[j] - x).squaredNorm();
      if (!used[j] && d < bd) bd = d, best = int(j);
    }
    if (best >= 0) used[size_t(best)] = 1, m.emplace_back(int(i), best);
  }
  return m;
}

Motion match_frames(const std::vector<Eigen::Vector2d>& A, const std::vector<Eigen::Vector2d>& B, double tol) {
  Motion best;
  const int na = int(A.size()), nb = int(B.size());
  for (int a1 = 0; a1 < na; ++a1)
    for (int a2 = a1 + 1; a2 < na; ++a2) {
      const Eigen::Vector2d da = A[a2] - A[a1];
      const double la = da.norm();
      if (la < 4 * tol) continue;  // too short to fix a rotation
      for (int b1 = 0; b1 < nb; ++b1)
        for (int b2 = 0; b2 < nb; ++b2) {
          if (b1 == b2) continue;
          const Eigen::Vector2d db = B[b2] - B[b1];
          if (std::abs(db.norm() - la) > tol) continue;
          const Eigen::Matrix2d R = rot2(std::atan2(db.y(), db.x()) - std::atan2(da.y(), da.x()));
          const Eigen::Vector2d t = B[b1] - R * A[a1];
          auto m = inliers_of(A, B, R, t, tol);
          if (m.size() > best.matches.size()) best = {R, t, std::move(m)};
        }
    }
  if (best.matches.size() >= 3) {
    // Least-squares rotation and shift on the inliers (2D Procrustes: the
    // angle of the summed cross and dot products about the centroids).
    Eigen::Vector2d ma = Eigen::Vector2d::Zero(), mb = Eigen::Vector2d::Zero();
    for (const auto& [i, j] : best.matches) ma += A[size_t(i)], mb += B[size_t(j)];
    ma /= double(best.matches.size()), mb /= double(best.matches.size());
    double cross = 0, dot = 0;
    for (const auto& [i, j] : best.matches) {
      const Eigen::Vector2d a = A[size_t(i)] - ma, b = B[size_t(j)] - mb;
      cross += a.x() * b.y() - a.y() * b.x();
      dot += a.dot(b);
    }
    best.R = rot2(std::atan2(cross, dot));
    best.t = mb - best.R * ma;
    best.matches = inliers_of(A, B, best.R, best.t, tol);
  }
  return best;
}

// b = R(theta_j - theta_i)(a - c) + c.
struct DotResidual {
  Eigen::Vector2d a, b;
  template <typename T>
  bool operator()(const T* c, const T* ti, const T* tj, T* r) const {
    const T d = tj[0] - ti[0];
    const T x = T(a.x()) - c[0], y = T(a.y()) - c[1];
    r[0] = ceres::cos(d) * x - ceres::sin(d) * y + c[0] - T(b.x());
    r[1] = ceres::sin(d) * x + ceres::cos(d) * y + c[1] - T(b.y());
    return true;
  }
};

}  // namespace

Result<MarkerResult> calibrate_table_markers(const std::vector<ImageU8>& colors, const std::vector<ImageU16>& depths,
                                             double unit, const Intrinsics& K, const MarkerOptions& o) {
  Stopwatch clock;
  const size_t n = colors.size();
  if (n < 2) return fail("markers: need at least two frames");
  if (depths.size() != n) return fail("markers: every frame needs depth (aligned to colour) to find the table plane");
  MarkerResult res;
  res.frames.resize(n);
  std::vector<std::vector<Dot>> dots(n);
  parallel_for(int(n), worker_count(o.threads), [&](int i) { dots[size_t(i)] = find_dots(colors[size_t(i)], depths[size_t(i)], unit, K, o); });
  // The table plane over every frame's dots.
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  for (size_t i = 0; i < n; ++i) {
    res.frames[i].dots = int(dots[i].size());
    for (const auto& d : dots[i])
      if (d.depth_point) cloud->push_back(pcl::PointXYZ(float(d.depth_point->x()), float(d.depth_point->y()), float(d.depth_point->z())));
  }
  if (cloud->size() < 10)
    return fail(fmt::format("markers: found {} dots with depth in {} frames; need white dots on a dark turntable", cloud->size(), n));
  pcl::SampleConsensusModelPlane<pcl::PointXYZ>::Ptr model(new pcl::SampleConsensusModelPlane<pcl::PointXYZ>(cloud));
  pcl::RandomSampleConsensus<pcl::PointXYZ> ransac(model);
  ransac.setDistanceThreshold(o.plane_tolerance_m);
  ransac.setMaxIterations(2000);
  if (!ransac.computeModel()) return fail("markers: no table plane through the dots");
  std::vector<int> inl;
  ransac.getInliers(inl);
  Eigen::VectorXf coeff;
  ransac.getModelCoefficients(coeff);
  Eigen::VectorXf refined;
  model->optimizeModelCoefficients(inl, coeff, refined);
  Eigen::Vector3d normal = refined.head<3>().cast<double>();
  double offset = refined[3];
  const double len = normal.norm();
  normal /= len, offset /= len;
  if (offset < 0) normal = -normal, offset = -offset;  // the camera (origin) on the positive side: n points up
  res.plane << normal, offset;
  // Plane coordinates: e1, e2, n right-handed; a point's (e1, e2) components
  // relative to the foot of the camera's perpendicular.
  const Eigen::Vector3d origin = -offset * normal;
  const Eigen::Vector3d e1 = normal.unitOrthogonal(), e2 = normal.cross(e1);
  std::vector<std::vector<Eigen::Vector2d>> uv(n);
  for (size_t i = 0; i < n; ++i)
    for (const auto& d : dots[i]) {
      if (!d.depth_point || std::abs(normal.dot(*d.depth_point) + offset) > o.plane_tolerance_m) continue;
      // Where the pixel's ray meets the plane.
      auto ray = K.unproject(d.pixel, 1.0);
      if (!ray) continue;
      const double denom = normal.dot(*ray);
      if (std::abs(denom) < 1e-9) continue;
      const Eigen::Vector3d x = *ray * (-offset / denom) - origin;
      uv[i].push_back({e1.dot(x), e2.dot(x)});
      ++res.frames[i].on_plane;
    }
  // Matches between every pair of frames.
  struct PairMatch {
    int i, j;
    Motion m;
  };
  std::vector<PairMatch> pairs;
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j) pairs.push_back({int(i), int(j), {}});
  parallel_for(int(pairs.size()), worker_count(o.threads), [&](int k) {
    auto& p = pairs[size_t(k)];
    p.m = match_frames(uv[size_t(p.i)], uv[size_t(p.j)], o.match_tolerance_m);
  });
  std::erase_if(pairs, [&](const PairMatch& p) { return int(p.m.matches.size()) < o.min_matches; });
  res.matched_pairs = int(pairs.size());
  // Every frame must be reached from frame 0 through matched pairs; the
  // start angles come from a walk along them.
  std::vector<double> theta(n, std::numeric_limits<double>::quiet_NaN());
  theta[0] = 0;
  for (bool grew = true; grew;) {
    grew = false;
    for (const auto& p : pairs) {
      const double a = std::atan2(p.m.R(1, 0), p.m.R(0, 0));
      if (std::isfinite(theta[size_t(p.i)]) && !std::isfinite(theta[size_t(p.j)])) theta[size_t(p.j)] = theta[size_t(p.i)] + a, grew = true;
      else if (std::isfinite(theta[size_t(p.j)]) && !std::isfinite(theta[size_t(p.i)])) theta[size_t(p.i)] = theta[size_t(p.j)] - a, grew = true;
    }
  }
  for (size_t i = 0; i < n; ++i)
    if (!std::isfinite(theta[i]))
      return fail(fmt::format("markers: frame {} shares fewer than {} dots with any frame linked to frame 0 ({} dots on the table)", i,
                              o.min_matches, res.frames[i].on_plane));
  // The centre: the fixed point of the pairs' motions, weighted by how well
  // each fixes it (|I - R| grows with the angle).
  Eigen::Matrix2d AtA = Eigen::Matrix2d::Zero();
  Eigen::Vector2d Atb = Eigen::Vector2d::Zero();
  for (const auto& p : pairs) {
    const Eigen::Matrix2d A = Eigen::Matrix2d::Identity() - p.m.R;
    AtA += A.transpose() * A;
    Atb += A.transpose() * p.m.t;
  }
  Eigen::Vector2d c = AtA.ldlt().solve(Atb);
  // Joint fit.
  ceres::Problem problem;
  auto* loss = new ceres::HuberLoss(o.match_tolerance_m / 2);  // owned by the problem (shared blocks: deleted once)
  size_t residuals = 0;
  for (const auto& p : pairs)
    for (const auto& [a, b] : p.m.matches) {
      auto* cost = new ceres::AutoDiffCostFunction<DotResidual, 2, 2, 1, 1>(
          new DotResidual{uv[size_t(p.i)][size_t(a)], uv[size_t(p.j)][size_t(b)]});
      problem.AddResidualBlock(cost, loss, c.data(), &theta[size_t(p.i)], &theta[size_t(p.j)]);
      ++residuals;
    }
  problem.SetParameterBlockConstant(&theta[0]);
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = 100;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  double sum2 = 0;
  for (const auto& p : pairs)
    for (const auto& [a, b] : p.m.matches) {
      double r[2];
      DotResidual{uv[size_t(p.i)][size_t(a)], uv[size_t(p.j)][size_t(b)]}(c.data(), &theta[size_t(p.i)], &theta[size_t(p.j)], r);
      sum2 += r[0] * r[0] + r[1] * r[1];
    }
  res.rms_m = residuals ? std::sqrt(sum2 / double(residuals)) : 0;
  res.axis.direction_camera = normal;
  res.axis.point_camera = origin + c.x() * e1 + c.y() * e2;
  res.axis.rms_m = res.rms_m;
  // The table's reach: its farthest dot from the centre, with a margin for
  // the rim beyond the outermost dots.
  double reach = 0;
  for (const auto& f : uv)
    for (const auto& p : f) reach = std::max(reach, (p - c).norm());
  res.axis.table_radius_m = 1.1 * reach + 0.01;
  for (size_t i = 0; i < n; ++i) {
    const double deg = std::remainder(theta[i] / kDeg, 360.0);
    res.axis.frame_angles_deg.push_back(deg);
  }
  Report& rep = res.report;
  rep.stage = "calibrate.markers";
  rep.errors["dot_rms_m"] = res.rms_m;
  rep.counts["frames"] = double(n);
  rep.counts["matched_frame_pairs"] = double(res.matched_pairs);
  rep.counts["dot_matches"] = double(residuals);
  rep.counts["plane_inlier_dots"] = double(inl.size());
  rep.params["table_radius_m"] = res.axis.table_radius_m;
  rep.counts["solver_iterations"] = double(summary.iterations.size());
  int least = INT32_MAX;
  for (const auto& f : res.frames) least = std::min(least, f.on_plane);
  rep.counts["least_dots_on_table"] = double(least);
  rep.skipped["dots_off_the_plane"] = double(cloud->size() - inl.size());
  rep.seconds = clock.seconds();
  return res;
}

Result<Report> run_markers_job(const std::filesystem::path& dir, const std::filesystem::path& out, const MarkerOptions& o) {
  auto s = load_session(dir);
  if (!s) return std::unexpected(s.error());
  if (!s->depth) return fail("'" + dir.string() + "': markers needs depth frames (aligned to colour) to find the table plane");
  if (!s->depth->aligned_to_color) return fail("'" + dir.string() + "': markers needs depth aligned to colour (same pixels)");
  std::vector<ImageU8> colors;
  std::vector<ImageU16> depths;
  std::optional<Intrinsics> K;
  for (const auto& f : s->frames) {
    auto c = load_color(*s, f);
    if (!c) return std::unexpected(c.error());
    auto d = load_depth(*s, f);
    if (!d) return std::unexpected(d.error());
    if (!K) K = s->color_intrinsics(f);
    colors.push_back(std::move(*c));
    depths.push_back(std::move(*d));
  }
  if (!K) return fail("'" + dir.string() + "': no colour intrinsics");
  auto r = calibrate_table_markers(colors, depths, s->depth->unit_m, *K, o);
  if (!r) return std::unexpected(r.error());
  Calibration cal;
  cal.color = SensorCalibration{*K, 0, 0};
  r->axis.frames_session = s->name;
  cal.axis = r->axis;
  if (auto st = save_calibration(out, cal); !st) return std::unexpected(st.error());
  Report rep = r->report;
  for (size_t i = 0; i < r->axis.frame_angles_deg.size(); ++i)
    rep.params[fmt::format("frame_{:02d}_angle_deg", i)] = r->axis.frame_angles_deg[i];
  rep.params["session"] = s->name;
  rep.params["calibration"] = out.string();
  return rep;
}

}  // namespace s2r
