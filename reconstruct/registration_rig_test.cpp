// Registration on the synthetic rig, whose poses are known exactly: the
// textured bunny, the symmetric vase (free mode slides and says so; the
// turntable mode holds), 40-deg steps, large depth holes, little overlap, a
// table angle 180 deg off.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <map>
#include <numbers>
#include <stdexcept>
#include <unistd.h>

#include "capture/synth_rig.h"
#include "core/camera_model.h"
#include "core/progress.h"
#include "reconstruct/registration.h"
#include "reconstruct/registration_input.h"

namespace fs = std::filesystem;
using namespace s2r;

namespace {

struct Rig {
  Session session;
  GroundTruth truth;
  Calibration cal;
};

// A synthetic session (made once per scene and view count in this process).
const Rig& rig(const std::string& scene, int views, double table_error_deg = 0) {
  static std::map<std::string, Rig> cache;
  const std::string key = scene + "_" + std::to_string(views) + "_" + std::to_string(table_error_deg);
  if (auto it = cache.find(key); it != cache.end()) return it->second;
  set_progress_enabled(false);
  const fs::path dir = fs::temp_directory_path() / ("s2r_reg_" + std::to_string(getpid())) / key;
  fs::remove_all(dir);
  fs::create_directories(dir.parent_path());
  SynthOptions o;
  o.scene = scene;
  o.views = views;
  o.seed = 11;
  o.table_error_deg = table_error_deg;
  o.data_dir = S2R_DATA_DIR;
  auto made = synth_session(o, dir);
  if (!made) throw std::runtime_error(made.error().message);  // gtest reports it as the test's failure
  Rig r;
  r.session = load_session(dir).value();
  r.truth = load_ground_truth(dir).value();
  // The calibration a user would have: the rig's axis (calibrate_axis_test
  // shows it is recovered to a fraction of a degree) and its intrinsics.
  TurntableAxis axis;
  axis.direction_camera = r.truth.axis_dir_camera;
  axis.point_camera = r.truth.axis_point_camera;
  r.cal.axis = axis;
  r.cal.depth = SensorCalibration{r.truth.depth, 0, 0};
  r.cal.color_from_depth = r.truth.color_from_depth;
  return cache.emplace(key, std::move(r)).first->second;
}

// The textured object is the Stanford bunny (real data, ../shared/data).
bool have_bunny() { return fs::exists(fs::path(S2R_DATA_DIR) / "stanford_bunny" / "bun_zipper.ply"); }
const std::string kNoBunny = std::string("no Stanford bunny in ") + S2R_DATA_DIR;

struct Outcome {
  RegistrationResult result;
  PoseError error;
};

Outcome run(const Rig& rig, RegistrationOptions o, double perturb_deg = 0, double perturb_m = 0,
            const std::function<void(RegistrationInput&)>& edit = {}) {
  auto in = load_session_views(rig.session, &rig.cal, {});
  EXPECT_TRUE(in) << in.error().message;
  if (edit) edit(*in);
  const Eigen::Vector3d centre = points_centre(in->views, in->given, 32);
  if (perturb_deg > 0 || perturb_m > 0) {
    const auto start = perturb_poses(in->given, perturb_deg, perturb_m, 3, centre);
    for (size_t i = 0; i < in->views.size(); ++i) in->views[i].initial = start[i];
  }
  o.turntable = in->turntable;
  o.progress = false;
  auto r = register_views(in->views, o);
  EXPECT_TRUE(r) << r.error().message;
  // Truth in the object frame; ours in the table frame at angle 0: compare
  // with the gauge on view 0, at the object's centre.
  std::vector<Eigen::Isometry3d> truth;
  for (int f : in->frames) truth.push_back(rig.truth.world_from_camera[static_cast<size_t>(f)]);
  const Eigen::Isometry3d object_from_table = truth[0] * r->poses[0].inverse();
  Outcome out{std::move(*r), {}};
  // (centre is in the table frame; the truth's frame is the object's)
  out.error = pose_error(out.result.poses, truth, object_from_table * centre, 0);
  if (getenv("VERBOSE"))
    for (size_t i = 0; i < out.error.rotation_deg.size(); ++i)
      std::printf("    view %zu: %.3f deg %.3f mm rms %.3f flagged %d flipped %d angle sens %.4f held %d %s\n", i,
                  out.error.rotation_deg[i], 1e3 * out.error.translation_m[i], 1e3 * out.result.views[i].rms_m,
                  out.result.views[i].flagged, out.result.views[i].flipped, out.result.views[i].angle_sensitivity,
                  out.result.views[i].angle_held, out.result.views[i].note.c_str());
  std::printf("  max error %.3f deg %.3f mm, rms %.3f mm, %d iterations, %.1f s; %s\n", out.error.max_rotation_deg,
              1e3 * out.error.max_translation_m, 1e3 * out.result.rms_m, out.result.iterations, out.result.seconds,
              out.result.slide.description.c_str());
  return out;
}

// Under sanitizers (S2R_SANITIZED) a twelve-view case costs minutes (the
// vase's two registrations took 600 s of the test's 777): the suite keeps the
// four-view ring there, which reaches the same code (preparation,
// correspondences, the solver, flags); reconstruct_registration_test covers
// slides, flips and outliers instrumented, and every case here runs in the
// optimised build (scripts/test runs the slow label there).
#ifdef S2R_SANITIZED
#define S2R_OPTIMISED_ONLY() GTEST_SKIP() << "runs in the optimised build only (too slow under sanitizers)"
#else
#define S2R_OPTIMISED_ONLY() (void)0
#endif

}  // namespace

TEST(RigRegistration, TexturedObjectFreeModeFromPerturbedPoses) {
  S2R_OPTIMISED_ONLY();
  if (!have_bunny()) GTEST_SKIP() << kNoBunny;
  const Rig& r = rig("bunny", 12);
  RegistrationOptions o;
  auto out = run(r, o, 5, 0.005);
  EXPECT_LT(out.error.max_rotation_deg, 0.1);
  EXPECT_LT(out.error.max_translation_m, 0.0005);
  EXPECT_FALSE(out.result.slide.slide) << out.result.slide.description;
  for (const auto& v : out.result.views) EXPECT_FALSE(v.flagged) << v.note;
}

TEST(RigRegistration, TexturedObjectTurntableModeCorrectsTableError) {
  S2R_OPTIMISED_ONLY();
  // The table turns 0.1 deg per step less than commanded (1.1 deg by the
  // last view): the angle correction takes it up.
  if (!have_bunny()) GTEST_SKIP() << kNoBunny;
  const Rig& r = rig("bunny", 12, 0.1);
  RegistrationOptions o;
  o.mode = RegistrationMode::kTurntable;
  auto out = run(r, o);
  EXPECT_LT(out.error.max_rotation_deg, 0.1);
  EXPECT_LT(out.error.max_translation_m, 0.0005);
}

TEST(RigRegistration, SymmetricObjectSlidesInFreeModeAndHoldsOnTheTurntable) {
  S2R_OPTIMISED_ONLY();
  const Rig& r = rig("vase", 12);
  RegistrationOptions o;
  auto free = run(r, o, 3, 0.003);
  EXPECT_TRUE(free.result.slide.slide) << free.result.slide.description;
  EXPECT_GE(free.result.slide.sliding_views, 6);
  EXPECT_LT(free.result.slide.angle_to_table_axis_deg, 10) << "the slide is a turn about the table axis";
  EXPECT_GT(free.error.max_rotation_deg, 0.5) << "free mode really does leave the angle undetermined";
  o.mode = RegistrationMode::kTurntable;
  auto held = run(r, o);
  EXPECT_LT(held.error.max_rotation_deg, 0.2);
  EXPECT_LT(held.error.max_translation_m, 0.0005);
}

TEST(RigRegistration, FortyDegreeSteps) {
  S2R_OPTIMISED_ONLY();
  if (!have_bunny()) GTEST_SKIP() << kNoBunny;
  const Rig& r = rig("bunny", 9);
  RegistrationOptions o;
  auto out = run(r, o, 5, 0.005);
  EXPECT_LT(out.error.max_rotation_deg, 0.1);
  EXPECT_LT(out.error.max_translation_m, 0.0005);
}

TEST(RigRegistration, LargeDepthHoles) {
  S2R_OPTIMISED_ONLY();
  // Every other view loses the left 40 % of its points (a reflective patch,
  // a sensor dropout).
  if (!have_bunny()) GTEST_SKIP() << kNoBunny;
  const Rig& r = rig("bunny", 12);
  RegistrationOptions o;
  auto out = run(r, o, 5, 0.005, [](RegistrationInput& in) {
    for (size_t i = 1; i < in.views.size(); i += 2) {
      ViewCloud& c = in.views[i].cloud;
      float lo = 1e9f, hi = -1e9f;
      for (const auto& p : c.points) lo = std::min(lo, p.x()), hi = std::max(hi, p.x());
      ViewCloud kept;
      for (size_t k = 0; k < c.size(); ++k)
        if (c.points[k].x() > lo + 0.4f * (hi - lo))
          kept.points.push_back(c.points[k]), kept.normals.push_back(c.normals[k]), kept.edge.push_back(c.edge[k]);
      c = std::move(kept);
    }
  });
  EXPECT_LT(out.error.max_rotation_deg, 0.15);
  EXPECT_LT(out.error.max_translation_m, 0.0005);
}

TEST(RigRegistration, LittleOverlapIsRegisteredOrFlagged) {
  // Four views 90 deg apart: neighbours share a thin strip.
  if (!have_bunny()) GTEST_SKIP() << kNoBunny;
  const Rig& r = rig("bunny", 4);
  RegistrationOptions o;
  auto out = run(r, o, 3, 0.003);
  double least = 1;
  for (const auto& p : out.result.pairs) least = std::min(least, p.overlap);
  std::printf("  least pair overlap %.2f\n", least);
  for (size_t i = 0; i < out.result.views.size(); ++i) {
    const bool good = out.error.rotation_deg[i] < 0.2 && out.error.translation_m[i] < 0.001;
    EXPECT_TRUE(good || out.result.views[i].flagged) << "view " << i << " off by " << out.error.rotation_deg[i]
                                                     << " deg and not flagged";
  }
}

TEST(RigRegistration, TableAngle180DegreesOffIsDetected) {
  S2R_OPTIMISED_ONLY();
  if (!have_bunny()) GTEST_SKIP() << kNoBunny;
  const Rig& r = rig("bunny", 12);
  RegistrationOptions o;
  o.mode = RegistrationMode::kFree;
  auto out = run(r, o, 0, 0, [](RegistrationInput& in) {
    // Frame 5's reported angle was 180 deg off.
    in.views[5].initial = rotation_about_axis(in.turntable->direction, in.turntable->point, std::numbers::pi) *
                          in.views[5].initial;
  });
  EXPECT_TRUE(out.result.views[5].flipped) << out.result.views[5].note;
  EXPECT_LT(out.error.max_rotation_deg, 0.1);
}
