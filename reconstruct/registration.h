// Simultaneous registration of all views (after Neugebauer, "Geometrical cloning of 3D
// objects via simultaneous registration of multiple range images", 1997): one Ceres
// problem over every view pose, point-to-plane residuals between every pair of
// views found to overlap, a robust (Huber) loss, correspondences re-found on a
// coarse-to-fine voxel schedule.
//
// Two parameterisations:
//   free       each view: a unit quaternion (Eigen quaternion manifold) and a
//              translation; the fixed view is held constant.
//   turntable  each view: its initial pose (table angle about the calibrated
//              axis) times a small correction: an angle about the axis, a tilt
//              off it and a shift, each with a Gaussian prior (the table's
//              repeatability). A rotationally symmetric object cannot slide
//              about the axis: only the prior would move it.
//
// In free mode the Gauss-Newton Hessian at the solution is examined: its
// weakest direction gives the pose uncertainty the data leaves, so a slide
// (a symmetric object, too little overlap) is reported rather than hidden.
// A view whose residual or overlap is implausible is flagged, and a flagged
// view is tried turned by 180 deg about the axis (a bad initial angle).
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/report.h"
#include "core/result.h"
#include "reconstruct/view_cloud.h"

namespace s2r {

struct RegistrationView {
  std::string name;
  ViewCloud cloud;  // full resolution, in the sensor frame
  Eigen::Isometry3d initial = Eigen::Isometry3d::Identity();  // world_from_sensor
};

enum class RegistrationMode { kFree, kTurntable };

// The turntable's axis in the world frame and how far its poses may be trusted.
struct TurntablePrior {
  Eigen::Vector3d direction = Eigen::Vector3d::UnitY();
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  double sigma_angle_deg = 0.2;   // table angle repeatability
  double sigma_tilt_deg = 0.1;    // rocking off the axis
  double sigma_shift_m = 0.0005;  // object shifting on the plate
};

// One round: correspondences found, then solved.
struct RegistrationRound {
  int level = 0, round = 0;
  double voxel_m = 0;
  int solver_iterations = 0;  // cumulative over the run
  double seconds = 0;         // since the start
  double rms_m = 0;           // point-to-plane RMS of this round's correspondences, after solving
  std::vector<Eigen::Isometry3d> poses;
};

struct RegistrationOptions {
  RegistrationMode mode = RegistrationMode::kFree;
  std::optional<TurntablePrior> turntable;  // required for kTurntable; the axis for the 180-deg test
  // Coarse-to-fine voxel sizes; empty: 8, 4, 2, 1 times extent/500 (the
  // bounding box's diagonal at the initial poses).
  std::vector<double> voxel_m;
  double reach_voxels = 4;         // correspondence distance, in voxels of the level
  int max_rounds_per_level = 8;    // correspondence re-finding per level
  int max_solver_iterations = 8;   // per round
  double converged_deg = 0.002, converged_m = 1e-5;  // pose change ending the last level
  int max_points_per_view = 3000;  // sources per view per level
  // Correspondences per ordered pair in the last level's problems (coarser
  // levels: 800), evenly spaced over the matched sources. Fewer leave the
  // answer depending on which sources were kept: on the Stanford bunny,
  // bun180 against bun000 spread over 0.22-0.29 deg across ten perturbed
  // starts with 800, 0.23-0.27 with 2000.
  int max_correspondences_per_pair = 2000;
  double max_normal_angle_deg = 45;
  double min_pair_overlap = 0.05;  // fraction of the smaller view with correspondences
  int fixed_view = 0;
  std::vector<int> variable_views;  // empty: every view but fixed_view
  // Flags: a view most of whose pairs fit with an RMS above ratio x the lower
  // quartile of the pairs' (and above half the final voxel), or whose
  // overlap with the others is below `flag_min_overlap`.
  double flag_rms_ratio = 3, flag_min_overlap = 0.1;
  bool try_flip = true;
  // A view's sensitivity below this is a slide (SlideAnalysis). Measured:
  // the rig's vase 0.006, the rig's bunny >= 0.021, the Stanford scans >= 0.065.
  double slide_sensitivity = 0.012;
  // Turntable mode: an angle whose sensitivity (the RMS change of the view's
  // residuals per unit of turn at the object's radius; normal noise alone
  // gives ~0.02) is below this is held at the table's. Measured: the vase
  // 0.020, the rig's bunny 0.16.
  double hold_angle_sensitivity = 0.05;
  int threads = 0;                // 0 = all cores
  bool progress = true;
  std::function<void(const RegistrationRound&)> on_round;  // bench history
};

struct PairStats {
  int a = 0, b = 0;
  double overlap = 0;  // fraction of the smaller view with a correspondence
  double rms_m = 0;
  int correspondences = 0;
};

struct ViewStats {
  double rms_m = 0;
  double overlap = 0;  // fraction of the view's points with a correspondence in any other view
  int pairs = 0;
  bool flagged = false;
  bool flipped = false;  // its initial rotation was 180 deg off and was corrected
  // Turntable mode: how strongly the data fix the view's angle about the axis
  // (as SlideAnalysis::sensitivity; -1 = not measured), and whether it was
  // held at the table's angle because they cannot.
  double angle_sensitivity = -1;
  bool angle_held = false;
  std::string note;
};

// How well the data pin each view down (free mode), from the Gauss-Newton
// Hessian at the solution. Per view, its 6x6 block (rotation measured as the
// displacement it causes at the object's radius) divided by the number of
// residuals touching the view: sqrt of its smallest eigenvalue is the
// view's *sensitivity*, the RMS change of its residuals per unit of motion
// along its weakest direction (1 = the residuals move as much as the view;
// a rotationally symmetric object gives ~0 about its axis). A view below
// `slide_sensitivity` can slide with an unchanged fit: reported, not hidden.
struct SlideAnalysis {
  bool computed = false;
  bool slide = false;
  double sensitivity = 0;      // smallest over views
  int view = -1;               // the view with the smallest sensitivity
  int weak_directions = 0;     // over all views: eigen-directions below the threshold
  int sliding_views = 0;
  Eigen::Vector3d rotation_axis = Eigen::Vector3d::Zero();  // world frame, of the weakest direction
  double rotation_share = 0;   // how much of the weakest direction is rotation (0..1)
  double angle_to_table_axis_deg = -1;                      // when the axis is known
  double sigma_deg = 0;        // statistical: rotation std. dev. along the whole problem's weakest direction
  std::string description;
};

struct RegistrationResult {
  std::vector<Eigen::Isometry3d> poses;  // world_from_sensor
  std::vector<ViewStats> views;
  std::vector<PairStats> pairs;
  double rms_m = 0;
  int iterations = 0, rounds = 0;
  double seconds = 0;
  std::vector<double> voxel_m;
  SlideAnalysis slide;
  std::vector<RegistrationRound> history;
  std::vector<std::string> warnings;
};

Result<RegistrationResult> register_views(const std::vector<RegistrationView>& views,
                                          const RegistrationOptions& options);

// Pose error of `estimated` against `truth` after aligning the gauge on view
// `ref`: rotation angle (deg) of each view's error transform, and how far it
// moves `centre` (m).
struct PoseError {
  std::vector<double> rotation_deg, translation_m;
  double max_rotation_deg = 0, max_translation_m = 0;
};
PoseError pose_error(const std::vector<Eigen::Isometry3d>& estimated,
                     const std::vector<Eigen::Isometry3d>& truth, const Eigen::Vector3d& centre, int ref = 0);

// Centre of the views' points placed by `poses` (every `stride`-th point):
// where pose errors are measured.
Eigen::Vector3d points_centre(const std::vector<RegistrationView>& views,
                              const std::vector<Eigen::Isometry3d>& poses, size_t stride = 16);

// Point-to-plane RMS of the views held at `poses`, at one voxel size: how well
// given poses fit, by the same measure the registration minimises (nothing is
// solved; `base` supplies the other options).
Result<double> fit_rms(std::vector<RegistrationView> views, const std::vector<Eigen::Isometry3d>& poses,
                       double voxel_m, RegistrationOptions base = {});

// The registration's figures in a stage report.
void add_to_report(const RegistrationResult& r, const std::vector<RegistrationView>& views, Report& report);

}  // namespace s2r
