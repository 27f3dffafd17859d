// Registration on synthetic point sets: the costs' derivatives, the quaternion
// parameterisation near 180 deg, slide detection, 180-deg initial angles,
// outliers, and the input checks. (Real scans: registration_data_test; the
// rig: registration_rig_test.)
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include <ceres/ceres.h>
#include <ceres/gradient_checker.h>

#include "core/camera_model.h"
#include "core/progress.h"
#include "reconstruct/register_job.h"
#include "reconstruct/registration.h"
#include "reconstruct/registration_costs.h"

using namespace s2r;
using Eigen::Vector3d;
using Eigen::Vector3f;

namespace {

constexpr double kPi = std::numbers::pi;

// Points of a closed surface r(theta, phi) sampled on a jittered grid, with
// normals from the surface's partial derivatives. lumps = 0 gives a sphere.
ViewCloud surface(double lumps, uint64_t seed, int n = 4000) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  auto r = [&](double th, double ph) {
    return 0.05 * (1 + lumps * (0.25 * std::sin(3 * th) * std::cos(2 * ph) + 0.15 * std::cos(5 * ph + 1) * std::sin(th)));
  };
  auto pos = [&](double th, double ph) -> Vector3d {
    return Vector3d(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th)) * r(th, ph);
  };
  ViewCloud c;
  for (int i = 0; i < n; ++i) {
    const double th = std::acos(1 - 2 * u(rng)), ph = 2 * kPi * u(rng);
    const double h = 1e-5;
    const Vector3d p = pos(th, ph);
    Vector3d n1 = (pos(th + h, ph) - pos(th - h, ph)).cross(pos(th, ph + h) - pos(th, ph - h));
    if (!(n1.norm() > 0)) continue;
    n1.normalize();
    if (n1.dot(p) < 0) n1 = -n1;
    c.points.push_back(p.cast<float>());
    c.normals.push_back(n1.cast<float>());
    c.edge.push_back(0);
  }
  return c;
}

// Two views of one surface; the second's sensor frame is turned by `deg`
// about `axis`: its points are expressed in that frame.
std::vector<RegistrationView> two_views(double lumps, double deg, const Vector3d& axis,
                                        Eigen::Isometry3d* truth_b) {
  const ViewCloud a = surface(lumps, 1), b_world = surface(lumps, 2);
  Eigen::Isometry3d world_from_b = rotation_about_axis(axis.normalized(), Vector3d(0.01, 0, 0), deg * kPi / 180);
  world_from_b.pretranslate(Vector3d(0.02, -0.01, 0.03));
  ViewCloud b;
  const Eigen::Isometry3d b_from_world = world_from_b.inverse();
  for (size_t i = 0; i < b_world.size(); ++i) {
    b.points.push_back((b_from_world * b_world.points[i].cast<double>()).cast<float>());
    b.normals.push_back((b_from_world.linear() * b_world.normals[i].cast<double>()).cast<float>());
    b.edge.push_back(0);
  }
  *truth_b = world_from_b;
  return {{"a", a, Eigen::Isometry3d::Identity()}, {"b", b, world_from_b}};
}

RegistrationOptions quiet() {
  RegistrationOptions o;
  o.progress = false;
  return o;
}

}  // namespace

TEST(RegistrationCosts, AutomaticDerivativesMatchNumericOnes) {
  ceres::NumericDiffOptions nd;
  nd.relative_step_size = 1e-6;
  ceres::GradientChecker::ProbeResults results;
  {
    ceres::AutoDiffCostFunction<reg::FreePointToPlane, 1, 4, 3, 4, 3> cost(new reg::FreePointToPlane{
        Vector3d(0.01, 0.02, 0.4), Vector3d(-0.02, 0.01, 0.38), Vector3d(0.1, -0.2, 0.97).normalized(), 1000});
    Eigen::Quaterniond qa(Eigen::AngleAxisd(0.3, Vector3d(1, 2, 3).normalized()));
    Eigen::Quaterniond qb(Eigen::AngleAxisd(3.1, Vector3d(-1, 0.5, 0.2).normalized()));  // near 180 deg
    double a[4] = {qa.x(), qa.y(), qa.z(), qa.w()}, b[4] = {qb.x(), qb.y(), qb.z(), qb.w()};
    double ta[3] = {0.01, -0.02, 0.03}, tb[3] = {-0.05, 0.02, 0.1};
    ceres::EigenQuaternionManifold quat;
    std::vector<const ceres::Manifold*> manifolds = {&quat, nullptr, &quat, nullptr};
    ceres::GradientChecker checker(&cost, &manifolds, nd);
    const double* params[] = {a, ta, b, tb};
    EXPECT_TRUE(checker.Probe(params, 1e-6, &results)) << results.error_log;
  }
  {
    reg::TurntableFrame f;
    f.d = Vector3d(0.05, -0.99, 0.1).normalized();
    f.c = Vector3d(0.01, 0.02, 0.45);
    f.e1 = f.d.unitOrthogonal();
    f.e2 = f.d.cross(f.e1);
    ceres::AutoDiffCostFunction<reg::TurntablePointToPlane, 1, 1, 2, 3, 1, 2, 3> cost(new reg::TurntablePointToPlane{
        f, Vector3d(0.03, 0.01, 0.42), Vector3d(0.02, 0.015, 0.43), Vector3d(0.3, 0.1, -0.95).normalized(), 500});
    double tha = 0.01, thb = -0.02, tia[2] = {0.001, -0.002}, tib[2] = {0.003, 0.0}, sha[3] = {1e-4, 0, -2e-4},
           shb[3] = {0, 3e-4, 1e-4};
    const std::vector<const ceres::Manifold*> none(6, nullptr);
    ceres::GradientChecker checker(&cost, &none, nd);
    const double* params[] = {&tha, tia, sha, &thb, tib, shb};
    EXPECT_TRUE(checker.Probe(params, 1e-6, &results)) << results.error_log;
  }
}

TEST(Registration, RecoversARotationOfAlmost180Degrees) {
  // The quaternion of the second view has w ~ 0: the parameterisation's
  // extreme; the manifold must still move it freely.
  for (double deg : {179.9, 180.0, -179.95}) {
    Eigen::Isometry3d truth;
    auto views = two_views(1.0, deg, Vector3d(0.2, 1, -0.1), &truth);
    views[1].initial = rotation_about_axis(Vector3d(1, 0.3, 0.2).normalized(), Vector3d::Zero(), 4 * kPi / 180) *
                       views[1].initial;
    views[1].initial.pretranslate(Vector3d(0.003, -0.002, 0.001));
    auto r = register_views(views, quiet());
    ASSERT_TRUE(r) << r.error().message;
    const PoseError e = pose_error(r->poses, {Eigen::Isometry3d::Identity(), truth}, Vector3d::Zero());
    EXPECT_LT(e.rotation_deg[1], 0.02) << deg;
    EXPECT_LT(e.translation_m[1], 2e-5) << deg;
    EXPECT_FALSE(r->slide.slide) << r->slide.description;
  }
}

TEST(Registration, SymmetricObjectSlideIsReportedNotHidden) {
  // A sphere: any rotation about its centre fits equally well.
  Eigen::Isometry3d truth;
  auto views = two_views(0.0, 30, Vector3d(0, 1, 0), &truth);
  auto r = register_views(views, quiet());
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_TRUE(r->slide.computed);
  EXPECT_TRUE(r->slide.slide) << r->slide.description;
  EXPECT_GE(r->slide.weak_directions, 3) << r->slide.description;
  EXPECT_LT(r->rms_m, 1e-3);  // the fit itself looks perfect: the slide is not visible in the RMS
  bool warned = false;
  for (const auto& w : r->warnings) warned |= w.find("slide") != std::string::npos;
  EXPECT_TRUE(warned);
  // The same with lumps is well determined.
  auto lumpy = two_views(1.0, 30, Vector3d(0, 1, 0), &truth);
  auto r2 = register_views(lumpy, quiet());
  ASSERT_TRUE(r2);
  EXPECT_FALSE(r2->slide.slide) << r2->slide.description;
  EXPECT_EQ(r2->slide.weak_directions, 0);
}

TEST(Registration, ThirtyPercentOutliers) {
  Eigen::Isometry3d truth;
  auto views = two_views(1.0, 25, Vector3d(0.1, 1, 0), &truth);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> u(-0.08f, 0.08f);
  for (auto& v : views) {
    const size_t n = v.cloud.size();
    for (size_t i = 0; i < n * 3 / 7; ++i) {  // 30 % of the result are outliers
      v.cloud.points.emplace_back(u(rng), u(rng), u(rng));
      v.cloud.normals.push_back(Vector3f(u(rng), u(rng), u(rng)).normalized());
      v.cloud.edge.push_back(0);
    }
  }
  views[1].initial = rotation_about_axis(Vector3d(0, 0, 1), Vector3d::Zero(), 5 * kPi / 180) * views[1].initial;
  auto r = register_views(views, quiet());
  ASSERT_TRUE(r) << r.error().message;
  const PoseError e = pose_error(r->poses, {Eigen::Isometry3d::Identity(), truth}, Vector3d::Zero());
  EXPECT_LT(e.rotation_deg[1], 0.1);
  EXPECT_LT(e.translation_m[1], 1e-4);
}

TEST(Registration, InitialRotation180DegreesOffIsDetectedAndCorrected) {
  // Four views of a lumpy object around the y axis; one starts turned by a
  // further 180 deg about that axis (a wrong table angle).
  std::vector<RegistrationView> views;
  std::vector<Eigen::Isometry3d> truth;
  const ViewCloud world = surface(1.0, 3, 12000);
  for (int k = 0; k < 4; ++k) {
    const Eigen::Isometry3d world_from_v = rotation_about_axis(Vector3d::UnitY(), Vector3d::Zero(), k * kPi / 2);
    // Each view keeps the half of the surface facing its sensor (+z of its frame).
    ViewCloud c;
    const Eigen::Isometry3d v_from_world = world_from_v.inverse();
    for (size_t i = 0; i < world.size(); ++i) {
      const Vector3d p = v_from_world * world.points[i].cast<double>();
      const Vector3d n = v_from_world.linear() * world.normals[i].cast<double>();
      if (n.z() < 0.1) continue;
      c.points.push_back(p.cast<float>());
      c.normals.push_back(n.cast<float>());
      c.edge.push_back(0);
    }
    views.push_back({"v" + std::to_string(k), c, world_from_v});
    truth.push_back(world_from_v);
  }
  views[2].initial = rotation_about_axis(Vector3d::UnitY(), Vector3d::Zero(), kPi) * views[2].initial;
  auto o = quiet();
  auto r = register_views(views, o);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_TRUE(r->views[2].flipped) << r->views[2].note;
  const PoseError e = pose_error(r->poses, truth, Vector3d::Zero());
  EXPECT_LT(e.max_rotation_deg, 0.05);
  bool warned = false;
  for (const auto& w : r->warnings) warned |= w.find("180 deg off") != std::string::npos;
  EXPECT_TRUE(warned);
  // Without the flip test the view is left flagged, never silently wrong.
  o.try_flip = false;
  auto r2 = register_views(views, o);
  ASSERT_TRUE(r2);
  const PoseError e2 = pose_error(r2->poses, truth, Vector3d::Zero());
  if (e2.rotation_deg[2] > 1) {
    EXPECT_TRUE(r2->views[2].flagged) << "a view left 180 deg off must be flagged";
    EXPECT_FALSE(r2->views[0].flagged || r2->views[1].flagged || r2->views[3].flagged) << "blame one view";
  }
}

TEST(Registration, BadInputIsAClearError) {
  Eigen::Isometry3d truth;
  auto views = two_views(1.0, 10, Vector3d(0, 1, 0), &truth);
  auto o = quiet();
  EXPECT_FALSE(register_views({views[0]}, o));
  auto bad = views;
  bad[1].initial.matrix()(0, 3) = std::nan("");
  auto r = register_views(bad, o);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("not finite"), std::string::npos);
  bad = views;
  bad[1].cloud.points.resize(5);
  EXPECT_FALSE(register_views(bad, o));
  o.mode = RegistrationMode::kTurntable;
  r = register_views(views, o);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("axis"), std::string::npos);
  o = quiet();
  o.voxel_m = {0.01, -1};
  EXPECT_FALSE(register_views(views, o));
  o = quiet();
  o.fixed_view = 7;
  EXPECT_FALSE(register_views(views, o));
}

TEST(Registration, ViewsThatDoNotOverlapAreFlagged) {
  Eigen::Isometry3d truth;
  auto views = two_views(1.0, 10, Vector3d(0, 1, 0), &truth);
  views.push_back(views[1]);
  views[2].name = "far away";
  views[2].initial.pretranslate(Vector3d(1, 0, 0));  // a metre off: overlaps nothing
  auto r = register_views(views, quiet());
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_TRUE(r->views[2].flagged);
  EXPECT_NE(r->views[2].note.find("overlap"), std::string::npos);
  EXPECT_FALSE(r->views[1].flagged);
}

// The registered poses against the turntable's own: a known turn about a
// tilted axis and a known tilt off it come back as they were made, with the
// turn's sign (right-handed about the axis) and wherever the view sits.
TEST(Registration, TurnAndTiltFromTheTableAreSeparated) {
  const Vector3d axis = Vector3d(0.05, -0.84, -0.53).normalized();
  const Vector3d off = axis.unitOrthogonal();
  std::vector<Eigen::Isometry3d> table, registered;
  const double turns[] = {0, 1.2, -0.7, 0.3}, tilts[] = {0, 0, 0.2, 0.05};
  for (int i = 0; i < 4; ++i) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = Eigen::AngleAxisd(kPi / 2 * i, axis).toRotationMatrix();
    t.translation() = Vector3d(0.01 * i, 0.3, -0.02);
    table.push_back(t);
    Eigen::Isometry3d r = t;
    r.linear() = (Eigen::AngleAxisd(tilts[i] * kPi / 180, off) * Eigen::AngleAxisd(turns[i] * kPi / 180, axis)).toRotationMatrix() *
                 t.linear();
    registered.push_back(r);
  }
  const TableAgreement a = table_agreement(registered, table, -2 * axis);  // the axis' length and sign as given
  ASSERT_EQ(a.turn_deg.size(), 4u);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(-a.turn_deg[size_t(i)], turns[i], 1e-3) << i;  // the axis was given reversed
    EXPECT_NEAR(a.tilt_deg[size_t(i)], tilts[i], 1e-3) << i;
  }
  EXPECT_NEAR(a.max_turn_deg, 1.2, 1e-3);
  EXPECT_NEAR(a.max_tilt_deg, 0.2, 1e-3);
  EXPECT_NEAR(a.rms_turn_deg, std::sqrt((1.44 + 0.49 + 0.09) / 4), 1e-3);
}
