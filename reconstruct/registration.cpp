#include "reconstruct/registration.h"
#include "core/angles.h"

#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <numbers>

#include <ceres/ceres.h>

#include "calibrate/turntable_axis.h"
#include "core/camera_model.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "reconstruct/registration_costs.h"

namespace s2r {

namespace {


struct Correspondence {
  Eigen::Vector3d p_a, q_b, n_b;  // sensor frames of a and b
};

struct PairData {
  int a = 0, b = 0;
  std::vector<Correspondence> ab;  // a's points onto b's surface
  size_t sources_a = 0;
  std::vector<uint8_t> matched_a;  // per source point of a
};

// A level's clouds: down-sampled, sources subsampled, k-d trees.
struct LevelView {
  ViewCloud cloud;
  std::vector<int> sources;
  std::unique_ptr<NeighbourIndex> index;
};


double rotation_deg(const Eigen::Matrix3d& r) { return Eigen::AngleAxisd(r).angle() / kDeg; }

// The poses being optimised, in either parameterisation.
class PoseState {
 public:
  PoseState(const std::vector<Eigen::Isometry3d>& initial, RegistrationMode mode,
            const std::optional<TurntablePrior>& tt)
      : mode_(mode), initial_(initial) {
    const size_t n = initial.size();
    if (mode == RegistrationMode::kFree) {
      q_.resize(n);
      t_.resize(n);
      for (size_t i = 0; i < n; ++i) {
        const Eigen::Quaterniond q(initial[i].rotation());
        q_[i] = {q.x(), q.y(), q.z(), q.w()};
        const Eigen::Vector3d t = initial[i].translation();
        t_[i] = {t.x(), t.y(), t.z()};
      }
    } else {
      frame_.d = tt->direction.normalized();
      frame_.c = tt->point;
      frame_.e1 = frame_.d.unitOrthogonal();
      frame_.e2 = frame_.d.cross(frame_.e1);
      theta_.assign(n, 0.0);
      tilt_.assign(n, {0, 0});
      shift_.assign(n, {0, 0, 0});
    }
  }

  Eigen::Isometry3d pose(size_t i) const {
    if (mode_ == RegistrationMode::kFree) {
      Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
      t.linear() = Eigen::Quaterniond(q_[i][3], q_[i][0], q_[i][1], q_[i][2]).normalized().toRotationMatrix();
      t.translation() = Eigen::Vector3d(t_[i][0], t_[i][1], t_[i][2]);
      return t;
    }
    // Apply the correction to the initial pose's origin and axes.
    const Eigen::Isometry3d& p0 = initial_[i];
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    const Eigen::Vector3d o = reg::turntable_apply<double>(frame_, &theta_[i], tilt_[i].data(), shift_[i].data(),
                                                           p0.translation(), false);
    for (int k = 0; k < 3; ++k)
      t.linear().col(k) = reg::turntable_apply<double>(frame_, &theta_[i], tilt_[i].data(), shift_[i].data(),
                                                       p0.linear().col(k), true);
    t.translation() = o;
    return t;
  }

  RegistrationMode mode_;
  std::vector<Eigen::Isometry3d> initial_;
  std::vector<std::array<double, 4>> q_;  // x y z w
  std::vector<std::array<double, 3>> t_;
  reg::TurntableFrame frame_;
  std::vector<double> theta_;
  std::vector<std::array<double, 2>> tilt_;
  std::vector<std::array<double, 3>> shift_;
};

struct Extent {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double radius = 0;  // half the bounding-box diagonal
};

Extent extent_of(const std::vector<RegistrationView>& views, const std::vector<Eigen::Isometry3d>& poses) {
  Eigen::AlignedBox3d box;
  for (size_t i = 0; i < views.size(); ++i) {
    const auto& pts = views[i].cloud.points;
    const size_t step = std::max<size_t>(1, pts.size() / 2000);
    for (size_t k = 0; k < pts.size(); k += step) box.extend(poses[i] * pts[k].cast<double>());
  }
  Extent e;
  if (box.isEmpty()) return e;
  e.centre = box.center();
  e.radius = 0.5 * box.diagonal().norm();
  return e;
}

// Correspondences of a onto b at the current poses. A first pass over every
// 8th source point gives up early on pairs that clearly do not overlap.
void find_pair(PairData& pd, const LevelView& va, const LevelView& vb, const Eigen::Isometry3d& ta,
               const Eigen::Isometry3d& tb, float reach, double cos_max, size_t cap, double min_overlap) {
  pd.ab.clear();
  pd.sources_a = va.sources.size();
  pd.matched_a.assign(va.sources.size(), 0);
  const Eigen::Isometry3d b_from_a = tb.inverse() * ta;
  const Eigen::Matrix3f r = b_from_a.rotation().cast<float>();
  const Eigen::Vector3f t = b_from_a.translation().cast<float>();
  auto match = [&](size_t s) {
    const int i = va.sources[s];
    if (va.cloud.edge[i]) return -1;  // neither end of a correspondence is an edge
    const Eigen::Vector3f x = r * va.cloud.points[i] + t;
    const int j = vb.index->nearest(x, reach);
    if (j < 0 || vb.cloud.edge[j]) return -1;
    if ((r * va.cloud.normals[i]).dot(vb.cloud.normals[j]) < cos_max) return -1;
    return j;
  };
  constexpr size_t kProbe = 8;
  std::vector<int> probe;  // match of every kProbe-th source, kept for the full pass
  size_t hits = 0;
  for (size_t s = 0; s < va.sources.size(); s += kProbe) hits += (probe.emplace_back(match(s)) >= 0);
  if (probe.size() > 20 && double(hits) / probe.size() < 0.5 * min_overlap) {
    // Too little overlap to use: record the probe's estimate only.
    for (size_t s = 0, k = 0; s < va.sources.size() && k < hits; s += kProbe, ++k) pd.matched_a[s] = 1;
    return;
  }
  const size_t stride = std::max<size_t>(1, va.sources.size() / std::max<size_t>(1, cap));
  for (size_t s = 0; s < va.sources.size(); ++s) {
    const int j = s % kProbe == 0 ? probe[s / kProbe] : match(s);
    if (j < 0) continue;
    pd.matched_a[s] = 1;
    if (s % stride != 0) continue;
    const int i = va.sources[s];
    pd.ab.push_back({va.cloud.points[i].cast<double>(), vb.cloud.points[j].cast<double>(),
                     vb.cloud.normals[j].cast<double>()});
  }
}

double pair_overlap(const PairData& ab, const PairData& ba) {
  auto frac = [](const PairData& p) {
    if (p.sources_a == 0) return 0.0;
    size_t m = 0;
    for (auto v : p.matched_a) m += v;
    return double(m) / p.sources_a;
  };
  return std::max(frac(ab), frac(ba));
}

double residual_m(const Correspondence& c, const Eigen::Isometry3d& ta, const Eigen::Isometry3d& tb) {
  return (tb.linear() * c.n_b).dot(ta * c.p_a - tb * c.q_b);
}

struct Run {
  const std::vector<RegistrationView>& views;
  const RegistrationOptions& o;
  Extent extent;
  std::vector<double> voxels;
  Stopwatch clock;
  double time_offset = 0;
  int iterations = 0, rounds = 0;
  std::vector<RegistrationRound> history;
  std::vector<PairData> final_pairs;  // last round's, ordered pairs (a, b) and (b, a) adjacent
  double final_sigma = 1;
  // Shared by every round's problem (which does not own them); the last
  // problem outlives the rounds for the Hessian analysis.
  ceres::HuberLoss loss{1.0};
  ceres::EigenQuaternionManifold quat_manifold;
  std::unique_ptr<ceres::Problem> last_problem;
  std::vector<double*> variable_blocks;  // free mode: q, t per variable view, in order
  std::vector<ceres::ResidualBlockId> data_blocks;  // turntable mode: the point-to-plane residuals
  std::vector<int> theta_views;                     // turntable mode: views with a free angle block
  std::vector<double> theta_sensitivity;            // per view, last measured (-1 = not measured)
};

bool is_variable(const RegistrationOptions& o, int i) {
  if (o.variable_views.empty()) return i != o.fixed_view;
  return std::find(o.variable_views.begin(), o.variable_views.end(), i) != o.variable_views.end();
}

// One round's problem: residuals for every active pair's correspondences.
std::unique_ptr<ceres::Problem> build_problem(Run& run, PoseState& st, const std::vector<PairData>& pairs,
                                              double sigma) {
  ceres::LossFunction* loss = &run.loss;
  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  auto problem = std::make_unique<ceres::Problem>(po);
  run.data_blocks.clear();
  const int n = static_cast<int>(run.views.size());
  const double inv_sigma = 1.0 / sigma;
  const bool free = st.mode_ == RegistrationMode::kFree;
  std::vector<uint8_t> used(static_cast<size_t>(n), 0);
  for (const auto& pd : pairs) {
    const bool var_a = is_variable(run.o, pd.a), var_b = is_variable(run.o, pd.b);
    if (!var_a && !var_b) continue;
    used[static_cast<size_t>(pd.a)] = used[static_cast<size_t>(pd.b)] = 1;
    for (const auto& c : pd.ab) {
      if (free) {
        auto* cost = new ceres::AutoDiffCostFunction<reg::FreePointToPlane, 1, 4, 3, 4, 3>(
            new reg::FreePointToPlane{c.p_a, c.q_b, c.n_b, inv_sigma});
        problem->AddResidualBlock(cost, loss, st.q_[pd.a].data(), st.t_[pd.a].data(), st.q_[pd.b].data(),
                                  st.t_[pd.b].data());
      } else {
        const auto& pa = st.initial_[pd.a];
        const auto& pb = st.initial_[pd.b];
        auto* cost = new ceres::AutoDiffCostFunction<reg::TurntablePointToPlane, 1, 1, 2, 3, 1, 2, 3>(
            new reg::TurntablePointToPlane{st.frame_, pa * c.p_a, pb * c.q_b, pb.linear() * c.n_b, inv_sigma});
        run.data_blocks.push_back(problem->AddResidualBlock(cost, loss, &st.theta_[pd.a], st.tilt_[pd.a].data(),
                                                            st.shift_[pd.a].data(), &st.theta_[pd.b],
                                                            st.tilt_[pd.b].data(), st.shift_[pd.b].data()));
      }
    }
  }
  run.variable_blocks.clear();
  run.theta_views.clear();
  for (int i = 0; i < n; ++i) {
    if (!used[static_cast<size_t>(i)]) continue;
    const bool var = is_variable(run.o, i);
    if (free) {
      problem->SetManifold(st.q_[i].data(), &run.quat_manifold);
      if (!var) {
        problem->SetParameterBlockConstant(st.q_[i].data());
        problem->SetParameterBlockConstant(st.t_[i].data());
      } else {
        run.variable_blocks.push_back(st.q_[i].data());
        run.variable_blocks.push_back(st.t_[i].data());
      }
    } else {
      const TurntablePrior& tt = *run.o.turntable;
      if (!var) {
        problem->SetParameterBlockConstant(&st.theta_[i]);
        problem->SetParameterBlockConstant(st.tilt_[i].data());
        problem->SetParameterBlockConstant(st.shift_[i].data());
        continue;
      }
      run.theta_views.push_back(i);
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<reg::CorrectionPrior<1>, 1, 1>(
                                    new reg::CorrectionPrior<1>{1.0 / (tt.sigma_angle_deg * kDeg)}),
                                nullptr, &st.theta_[i]);
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<reg::CorrectionPrior<2>, 2, 2>(
                                    new reg::CorrectionPrior<2>{1.0 / (tt.sigma_tilt_deg * kDeg)}),
                                nullptr, st.tilt_[i].data());
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<reg::CorrectionPrior<3>, 3, 3>(
                                    new reg::CorrectionPrior<3>{1.0 / tt.sigma_shift_m}),
                                nullptr, st.shift_[i].data());
    }
  }
  return problem;
}

// Turntable mode: how strongly the data fix each view's angle about the axis
// (the RMS change of its residuals per metre of turn at the object's radius).
// Where they cannot (a symmetric object), the angle is held at the table's:
// the noise would otherwise pull it, thousands of residuals outweighing the
// table's prior.
void hold_undetermined_angles(Run& run, PoseState& st, ceres::Problem& problem, double sigma) {
  if (run.theta_views.empty() || run.data_blocks.empty()) return;
  ceres::Problem::EvaluateOptions eo;
  eo.residual_blocks = run.data_blocks;
  for (int v : run.theta_views) eo.parameter_blocks.push_back(&st.theta_[v]);
  eo.num_threads = worker_count(run.o.threads);
  ceres::CRSMatrix crs;
  double cost = 0;
  if (!problem.Evaluate(eo, &cost, nullptr, nullptr, &crs)) return;
  std::vector<double> sum2(run.theta_views.size(), 0);
  std::vector<int> rows(run.theta_views.size(), 0);
  for (int r = 0; r < crs.num_rows; ++r)
    for (int k = crs.rows[r]; k < crs.rows[r + 1]; ++k) sum2[crs.cols[k]] += crs.values[k] * crs.values[k], ++rows[crs.cols[k]];
  const double radius = std::max(run.extent.radius, 1e-6);
  run.theta_sensitivity.assign(run.views.size(), -1);
  for (size_t k = 0; k < run.theta_views.size(); ++k) {
    if (rows[k] == 0) continue;
    const double s = std::sqrt(sum2[k] / rows[k]) * sigma / radius;  // d(residual m) / d(turn m at the radius)
    const int v = run.theta_views[k];
    run.theta_sensitivity[static_cast<size_t>(v)] = s;
    if (s < run.o.hold_angle_sensitivity) problem.SetParameterBlockConstant(&st.theta_[v]);
  }
}

// Coarse-to-fine rounds of (find correspondences, solve) from the current state.
Status run_levels(Run& run, PoseState& st) {
  const int n = static_cast<int>(run.views.size());
  const int threads = worker_count(run.o.threads);
  const double cos_max = std::cos(run.o.max_normal_angle_deg * kDeg);
  std::optional<Progress> progress;
  if (run.o.progress)
    progress.emplace("register", run.voxels.size() * static_cast<size_t>(run.o.max_rounds_per_level));
  auto tick = [&] {
    if (progress) progress->tick();
  };
  for (size_t level = 0; level < run.voxels.size(); ++level) {
    const double voxel = run.voxels[level];
    const float reach = static_cast<float>(run.o.reach_voxels * voxel);
    const double sigma = 0.25 * voxel;  // Huber scale: residuals beyond it count linearly
    std::vector<LevelView> lv(static_cast<size_t>(n));
    parallel_for(n, threads, [&](int i) {
      LevelView& v = lv[static_cast<size_t>(i)];
      v.cloud = downsample(run.views[static_cast<size_t>(i)].cloud, voxel);
      const size_t m = v.cloud.size();
      const size_t stride = std::max<size_t>(1, m / static_cast<size_t>(std::max(1, run.o.max_points_per_view)));
      for (size_t k = 0; k < m; k += stride) v.sources.push_back(static_cast<int>(k));
      v.index = std::make_unique<NeighbourIndex>(v.cloud.points);
    });
    std::vector<std::pair<int, int>> candidates;
    for (int a = 0; a < n; ++a)
      for (int b = a + 1; b < n; ++b)
        if (is_variable(run.o, a) || is_variable(run.o, b)) candidates.emplace_back(a, b);
    // Coarse levels end when the poses move by a twentieth of their voxel.
    const bool last = level + 1 == run.voxels.size();
    // The full count where the answer is settled; coarse levels only bring
    // the poses near it.
    const size_t cap = static_cast<size_t>(std::max(1, last ? run.o.max_correspondences_per_pair : 800));
    const double tol_m = last ? run.o.converged_m : std::max(run.o.converged_m, 0.05 * voxel);
    const double tol_deg = last ? run.o.converged_deg
                                : std::max(run.o.converged_deg, tol_m / std::max(run.extent.radius, 1e-6) / kDeg);
    int round = 0;
    for (; round < run.o.max_rounds_per_level; ++round, tick()) {
      std::vector<Eigen::Isometry3d> before(static_cast<size_t>(n));
      for (int i = 0; i < n; ++i) before[static_cast<size_t>(i)] = st.pose(static_cast<size_t>(i));
      // Correspondences both ways for every candidate pair; the pair is kept
      // when enough of the smaller view overlaps (found, not assumed).
      std::vector<PairData> found(candidates.size() * 2);
      parallel_for(static_cast<int>(candidates.size()), threads, [&](int k) {
        const auto [a, b] = candidates[static_cast<size_t>(k)];
        found[2 * k].a = a, found[2 * k].b = b, found[2 * k + 1].a = b, found[2 * k + 1].b = a;
        find_pair(found[2 * k], lv[a], lv[b], before[a], before[b], reach, cos_max, cap, run.o.min_pair_overlap);
        find_pair(found[2 * k + 1], lv[b], lv[a], before[b], before[a], reach, cos_max, cap, run.o.min_pair_overlap);
      });
      std::vector<PairData> pairs;
      for (size_t k = 0; k < candidates.size(); ++k) {
        const double ov = pair_overlap(found[2 * k], found[2 * k + 1]);
        if (ov < run.o.min_pair_overlap || found[2 * k].ab.size() + found[2 * k + 1].ab.size() < 12) continue;
        pairs.push_back(std::move(found[2 * k]));
        pairs.push_back(std::move(found[2 * k + 1]));
      }
      if (pairs.empty()) break;
      auto problem = build_problem(run, st, pairs, sigma);
      if (st.mode_ == RegistrationMode::kTurntable) hold_undetermined_angles(run, st, *problem, sigma);
      ceres::Solver::Options so;
      so.max_num_iterations = run.o.max_solver_iterations;
      so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
      so.sparse_linear_algebra_library_type = ceres::EIGEN_SPARSE;  // small system; CHOLMOD's OpenMP workers would spin
      so.num_threads = threads;
      so.logging_type = ceres::SILENT;
      ceres::Solver::Summary summary;
      ceres::Solve(so, problem.get(), &summary);
      run.iterations += static_cast<int>(summary.iterations.size()) - 1;
      ++run.rounds;
      // RMS after solving, over this round's correspondences.
      double sum2 = 0;
      size_t count = 0;
      double change_deg = 0, change_m = 0;
      std::vector<Eigen::Isometry3d> after(static_cast<size_t>(n));
      for (int i = 0; i < n; ++i) {
        after[static_cast<size_t>(i)] = st.pose(static_cast<size_t>(i));
        const Eigen::Isometry3d d = after[i] * before[i].inverse();
        change_deg = std::max(change_deg, rotation_deg(d.rotation()));
        change_m = std::max(change_m, (d * run.extent.centre - run.extent.centre).norm());
      }
      for (const auto& pd : pairs)
        for (const auto& c : pd.ab) {
          const double r = residual_m(c, after[pd.a], after[pd.b]);
          sum2 += r * r;
          ++count;
        }
      RegistrationRound rr;
      rr.level = static_cast<int>(level);
      rr.round = round;
      rr.voxel_m = voxel;
      rr.solver_iterations = run.iterations;
      rr.seconds = run.time_offset + run.clock.seconds();
      rr.rms_m = count ? std::sqrt(sum2 / count) : 0;
      rr.poses = after;
      if (run.o.on_round) run.o.on_round(rr);
      run.history.push_back(std::move(rr));
      run.final_pairs = std::move(pairs);
      run.final_sigma = sigma;
      run.last_problem = std::move(problem);
      if (change_deg < tol_deg && change_m < tol_m) break;
    }
    for (; round + 1 < run.o.max_rounds_per_level; ++round) tick();
  }
  if (progress) progress->done();
  return {};
}

// Per-pair and per-view statistics and flags at the final poses.
void summarise(Run& run, const PoseState& st, RegistrationResult& res) {
  const int n = static_cast<int>(run.views.size());
  res.poses.resize(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) res.poses[static_cast<size_t>(i)] = st.pose(static_cast<size_t>(i));
  res.views.assign(static_cast<size_t>(n), {});
  res.pairs.clear();
  std::vector<double> view_sum2(static_cast<size_t>(n), 0);
  std::vector<size_t> view_count(static_cast<size_t>(n), 0);
  std::vector<std::vector<uint8_t>> matched(static_cast<size_t>(n));
  double sum2 = 0;
  size_t count = 0;
  for (size_t k = 0; k + 1 < run.final_pairs.size(); k += 2) {
    const PairData& ab = run.final_pairs[k];
    const PairData& ba = run.final_pairs[k + 1];
    PairStats ps;
    ps.a = ab.a;
    ps.b = ab.b;
    ps.overlap = pair_overlap(ab, ba);
    double s2 = 0;
    for (const PairData* pd : {&ab, &ba}) {
      auto& m = matched[static_cast<size_t>(pd->a)];
      if (m.size() < pd->matched_a.size()) m.resize(pd->matched_a.size(), 0);
      for (size_t s = 0; s < pd->matched_a.size(); ++s) m[s] |= pd->matched_a[s];
      for (const auto& c : pd->ab) {
        const double r = residual_m(c, res.poses[pd->a], res.poses[pd->b]);
        s2 += r * r;
        view_sum2[pd->a] += r * r;
        view_sum2[pd->b] += r * r;
        ++view_count[pd->a];
        ++view_count[pd->b];
      }
      ps.correspondences += static_cast<int>(pd->ab.size());
    }
    ps.rms_m = ps.correspondences ? std::sqrt(s2 / ps.correspondences) : 0;
    sum2 += s2;
    count += static_cast<size_t>(ps.correspondences);
    ++res.views[ab.a].pairs;
    ++res.views[ab.b].pairs;
    res.pairs.push_back(ps);
  }
  res.rms_m = count ? std::sqrt(sum2 / count) : 0;
  for (int i = 0; i < n; ++i) {
    auto& v = res.views[static_cast<size_t>(i)];
    v.rms_m = view_count[i] ? std::sqrt(view_sum2[i] / view_count[i]) : 0;
    const auto& m = matched[static_cast<size_t>(i)];
    size_t hits = 0;
    for (auto x : m) hits += x;
    v.overlap = m.empty() ? 0 : double(hits) / m.size();
  }
  for (size_t i = 0; i < run.theta_sensitivity.size() && i < res.views.size(); ++i) {
    const double s = run.theta_sensitivity[i];
    res.views[i].angle_sensitivity = s;
    if (s >= 0 && s < run.o.hold_angle_sensitivity) {
      res.views[i].angle_held = true;
      res.views[i].note = fmt::format("angle held at the table's: the data cannot fix it (sensitivity {:.3f})", s);
    }
  }
  // A pair fits implausibly when its RMS is far above that of the better
  // pairs (the lower quartile: a wrong view spoils several pairs, which must
  // not raise the reference). A
  // wrong view spoils every pair it is in, so blame goes to the view whose
  // pairs are mostly implausible, one view at a time (its pairs then no
  // longer count against its neighbours).
  std::vector<double> pair_rms;
  for (const auto& p : res.pairs)
    if (p.correspondences > 0) pair_rms.push_back(p.rms_m);
  std::sort(pair_rms.begin(), pair_rms.end());
  const double median = pair_rms.empty() ? 0 : pair_rms[pair_rms.size() / 4];
  const double floor_m = 0.5 * run.voxels.back();
  auto implausible = [&](const PairStats& p) {
    return p.rms_m > run.o.flag_rms_ratio * median && p.rms_m > floor_m;
  };
  for (int i = 0; i < n; ++i) {
    auto& v = res.views[static_cast<size_t>(i)];
    if (v.pairs == 0) {
      v.flagged = true;
      v.note = "no overlap with any other view";
    } else if (v.overlap < run.o.flag_min_overlap) {
      v.flagged = true;
      v.note = fmt::format("overlap {:.1f} % is below {:.0f} %", 100 * v.overlap, 100 * run.o.flag_min_overlap);
    }
  }
  for (;;) {
    int worst = -1;
    double worst_share = 0.5, worst_rms = 0;
    for (int i = 0; i < n; ++i) {
      if (res.views[static_cast<size_t>(i)].flagged) continue;
      double bad = 0, all = 0, s2 = 0;
      for (const auto& p : res.pairs) {
        if (p.a != i && p.b != i) continue;
        const int other = p.a == i ? p.b : p.a;
        if (res.views[static_cast<size_t>(other)].flagged) continue;
        all += p.correspondences;
        if (implausible(p)) bad += p.correspondences, s2 += p.rms_m * p.rms_m * p.correspondences;
      }
      if (all > 0 && bad / all > worst_share) worst = i, worst_share = bad / all, worst_rms = std::sqrt(s2 / bad);
    }
    if (worst < 0) break;
    auto& v = res.views[static_cast<size_t>(worst)];
    v.flagged = true;
    v.note = fmt::format("residual {:.3f} mm with {:.0f} % of its neighbours is {:.1f}x the better pairs'",
                         1e3 * worst_rms, 100 * worst_share, worst_rms / median);
  }
}

// Per-view sensitivity from the Gauss-Newton Hessian (free mode); see SlideAnalysis.
SlideAnalysis analyse_slide(Run& run, const RegistrationResult& res) {
  SlideAnalysis sa;
  if (!run.last_problem || run.variable_blocks.empty()) return sa;
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = run.variable_blocks;
  eo.num_threads = worker_count(run.o.threads);
  ceres::CRSMatrix crs;
  double cost = 0;
  if (!run.last_problem->Evaluate(eo, &cost, nullptr, nullptr, &crs)) return sa;
  const int cols = crs.num_cols;  // tangent: 3 (quaternion, half-angle) + 3 per view
  const int nviews = cols / 6;
  // Units: rotation as displacement at the object's radius (u = R angle; the
  // quaternion tangent is half the angle), translation in metres; residuals
  // back in metres (they were divided by the level's sigma).
  const double radius = std::max(run.extent.radius, 1e-6);
  Eigen::VectorXd scale(cols);
  for (int k = 0; k < cols; ++k) scale[k] = ((k % 6) < 3 ? 1.0 / (2 * radius) : 1.0) * run.final_sigma;
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(cols, cols);
  std::vector<int> rows_of(static_cast<size_t>(nviews), 0);
  for (int r = 0; r < crs.num_rows; ++r) {
    int last_view = -1;
    for (int a = crs.rows[r]; a < crs.rows[r + 1]; ++a) {
      const int va = crs.cols[a] / 6;
      if (va != last_view) ++rows_of[static_cast<size_t>(va)], last_view = va;
      for (int b = crs.rows[r]; b < crs.rows[r + 1]; ++b)
        h(crs.cols[a], crs.cols[b]) += crs.values[a] * scale[crs.cols[a]] * crs.values[b] * scale[crs.cols[b]];
    }
  }
  // The variable views in block order.
  std::vector<int> view_of;
  for (int i = 0; i < static_cast<int>(run.views.size()); ++i)
    if (is_variable(run.o, i) && res.views[static_cast<size_t>(i)].pairs > 0)
      view_of.push_back(i);
  sa.sensitivity = std::numeric_limits<double>::infinity();
  for (int k = 0; k < nviews && k < static_cast<int>(view_of.size()); ++k) {
    if (rows_of[static_cast<size_t>(k)] == 0) continue;
    const Eigen::Matrix<double, 6, 6> block = h.block<6, 6>(6 * k, 6 * k) / rows_of[static_cast<size_t>(k)];
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(block);
    if (es.info() != Eigen::Success) continue;
    bool weak = false;
    for (int e = 0; e < 6; ++e)
      if (std::sqrt(std::max(0.0, es.eigenvalues()[e])) < run.o.slide_sensitivity) ++sa.weak_directions, weak = true;
    sa.sliding_views += weak;
    const double s = std::sqrt(std::max(0.0, es.eigenvalues()[0]));
    if (s < sa.sensitivity) {
      sa.sensitivity = s;
      sa.view = view_of[static_cast<size_t>(k)];
      const Eigen::Matrix<double, 6, 1> v = es.eigenvectors().col(0);
      sa.rotation_share = v.head<3>().norm();
      sa.rotation_axis = v.head<3>().norm() > 0 ? v.head<3>().normalized() : Eigen::Vector3d::Zero();
    }
  }
  if (!std::isfinite(sa.sensitivity)) return sa;
  sa.computed = true;
  // Statistical: the whole problem's weakest direction with residual noise = the RMS.
  {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(h);
    const double noise = std::max(res.rms_m, 1e-9);
    const double lmin = std::max(es.eigenvalues()[0], 1e-300);
    sa.sigma_deg = noise / std::sqrt(lmin) * es.eigenvectors().col(0).head<3>().norm() / radius / kDeg;
  }
  if (run.o.turntable && sa.rotation_axis.norm() > 0) {
    const double c = std::abs(sa.rotation_axis.dot(run.o.turntable->direction.normalized()));
    sa.angle_to_table_axis_deg = std::acos(std::min(1.0, c)) / kDeg;
  }
  sa.slide = sa.sensitivity < run.o.slide_sensitivity;
  sa.description = fmt::format(
      "{}: view {} is the least constrained, sensitivity {:.3f} (threshold {:.3f}) along a motion that is "
      "{:.0f} % rotation about ({:.2f}, {:.2f}, {:.2f}); {} view(s) with {} weak direction(s); statistical "
      "sigma {:.3f} deg",
      sa.slide ? "slide" : "no slide", sa.view, sa.sensitivity, run.o.slide_sensitivity, 100 * sa.rotation_share,
      sa.rotation_axis.x(), sa.rotation_axis.y(), sa.rotation_axis.z(), sa.sliding_views, sa.weak_directions,
      sa.sigma_deg);
  if (sa.angle_to_table_axis_deg >= 0)
    sa.description += fmt::format("; {:.1f} deg from the table axis", sa.angle_to_table_axis_deg);
  return sa;
}

std::vector<double> voxel_schedule(const RegistrationOptions& o, const Extent& e) {
  if (!o.voxel_m.empty()) return o.voxel_m;
  const double base = std::max(2 * e.radius / 500, 1e-5);
  return {8 * base, 4 * base, 2 * base, base};
}

Result<RegistrationResult> register_once(const std::vector<RegistrationView>& views,
                                         const std::vector<Eigen::Isometry3d>& initial,
                                         const RegistrationOptions& o, double time_offset) {
  Run run{views, o};
  run.time_offset = time_offset;
  run.extent = extent_of(views, initial);
  run.voxels = voxel_schedule(o, run.extent);
  PoseState st(initial, o.mode, o.turntable);
  if (auto s = run_levels(run, st); !s) return std::unexpected(s.error());
  RegistrationResult res;
  summarise(run, st, res);
  res.iterations = run.iterations;
  res.rounds = run.rounds;
  res.voxel_m = run.voxels;
  res.history = std::move(run.history);
  if (o.mode == RegistrationMode::kFree) res.slide = analyse_slide(run, res);
  res.seconds = run.clock.seconds();
  return res;
}

// The axis a bad initial angle would be off about: the table's, else one
// fitted through the initial poses, else the world's y through the centre.
std::pair<Eigen::Vector3d, Eigen::Vector3d> flip_axis(const std::vector<RegistrationView>& views,
                                                      const RegistrationOptions& o, const Extent& e) {
  if (o.turntable) return {o.turntable->direction.normalized(), o.turntable->point};
  std::vector<Eigen::Isometry3d> poses;
  for (const auto& v : views) poses.push_back(v.initial);
  if (poses.size() >= 3)
    if (auto fit = fit_axis_to_poses(poses); fit && fit->direction.allFinite() && fit->rms_m < e.radius)
      return {fit->direction.normalized(), fit->point};
  return {Eigen::Vector3d::UnitY(), e.centre};
}

}  // namespace

Result<RegistrationResult> register_views(const std::vector<RegistrationView>& views,
                                          const RegistrationOptions& o) {
  const int n = static_cast<int>(views.size());
  if (n < 2) return fail("registration needs at least two views (got " + std::to_string(n) + ")");
  if (o.fixed_view < 0 || o.fixed_view >= n) return fail("fixed view " + std::to_string(o.fixed_view) + " out of range");
  if (o.mode == RegistrationMode::kTurntable && !o.turntable)
    return fail("turntable-constrained registration needs the turntable axis (a calibration with an axis)");
  if (o.turntable && !(o.turntable->direction.norm() > 0.5 && o.turntable->point.allFinite() &&
                       o.turntable->sigma_angle_deg > 0 && o.turntable->sigma_tilt_deg > 0 &&
                       o.turntable->sigma_shift_m > 0))
    return fail("turntable prior: axis direction must be non-zero and every sigma positive");
  for (double v : o.voxel_m)
    if (!(v > 0) || !std::isfinite(v)) return fail("voxel sizes must be positive");
  for (int i = 0; i < n; ++i) {
    const auto& v = views[static_cast<size_t>(i)];
    if (!v.initial.matrix().allFinite())
      return fail("view " + std::to_string(i) + " (" + v.name + "): initial pose is not finite");
    if (v.cloud.size() < 20)
      return fail("view " + std::to_string(i) + " (" + v.name + "): only " + std::to_string(v.cloud.size()) +
                  " usable points (needs 20)");
  }
  std::vector<Eigen::Isometry3d> initial;
  for (const auto& v : views) initial.push_back(v.initial);
  Stopwatch clock;
  auto res = register_once(views, initial, o, 0);
  if (!res) return res;
  // A flagged view may have started 180 deg off: try it turned about the axis
  // with every other view held, and keep whichever fits.
  if (o.try_flip) {
    const Extent e = extent_of(views, res->poses);
    const auto [dir, point] = flip_axis(views, o, e);
    std::vector<int> flipped;
    std::vector<Eigen::Isometry3d> start = res->poses;
    for (int i = 0; i < n; ++i) {
      const ViewStats& vs = res->views[static_cast<size_t>(i)];
      if (!vs.flagged || !is_variable(o, i)) continue;
      RegistrationOptions one = o;
      one.variable_views = {i};
      one.try_flip = false;
      one.progress = false;
      one.mode = RegistrationMode::kFree;
      one.on_round = nullptr;
      std::vector<Eigen::Isometry3d> turned = res->poses;
      turned[static_cast<size_t>(i)] = rotation_about_axis(dir, point, std::numbers::pi) * res->poses[i];
      auto as_is = register_once(views, res->poses, one, 0);
      auto alt = register_once(views, turned, one, 0);
      if (!as_is || !alt) continue;
      const ViewStats& a = as_is->views[static_cast<size_t>(i)];
      const ViewStats& b = alt->views[static_cast<size_t>(i)];
      if (b.overlap > std::max(1.5 * a.overlap, o.flag_min_overlap) && (a.pairs == 0 || b.rms_m <= 1.5 * a.rms_m)) {
        start[static_cast<size_t>(i)] = alt->poses[static_cast<size_t>(i)];
        flipped.push_back(i);
      }
    }
    if (!flipped.empty()) {
      auto second = register_once(views, start, o, clock.seconds());
      if (!second) return second;
      second->history.insert(second->history.begin(), res->history.begin(), res->history.end());
      second->iterations += res->iterations;
      second->rounds += res->rounds;
      for (int i : flipped) {
        auto& v = second->views[static_cast<size_t>(i)];
        v.flipped = true;
        v.note = "initial rotation was 180 deg off about the axis; corrected" + (v.note.empty() ? "" : "; " + v.note);
        second->warnings.push_back("view " + std::to_string(i) + " (" + views[static_cast<size_t>(i)].name +
                                   "): initial rotation was 180 deg off; corrected");
      }
      res = std::move(second);
    }
  }
  for (int i = 0; i < n; ++i) {
    const auto& v = res->views[static_cast<size_t>(i)];
    if (v.flagged)
      res->warnings.push_back("view " + std::to_string(i) + " (" + views[static_cast<size_t>(i)].name +
                              ") flagged: " + v.note);
  }
  if (res->slide.slide) res->warnings.push_back(res->slide.description);
  res->seconds = clock.seconds();
  return res;
}

PoseError pose_error(const std::vector<Eigen::Isometry3d>& est, const std::vector<Eigen::Isometry3d>& truth,
                     const Eigen::Vector3d& centre, int ref) {
  PoseError e;
  const size_t n = std::min(est.size(), truth.size());
  if (n == 0 || ref < 0 || static_cast<size_t>(ref) >= n) return e;
  const Eigen::Isometry3d gauge = truth[ref] * est[ref].inverse();
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Isometry3d d = gauge * est[i] * truth[i].inverse();  // true placement -> estimated
    e.rotation_deg.push_back(rotation_deg(d.rotation()));
    e.translation_m.push_back((d * centre - centre).norm());
    e.max_rotation_deg = std::max(e.max_rotation_deg, e.rotation_deg.back());
    e.max_translation_m = std::max(e.max_translation_m, e.translation_m.back());
  }
  return e;
}

Eigen::Vector3d points_centre(const std::vector<RegistrationView>& views,
                              const std::vector<Eigen::Isometry3d>& poses, size_t stride) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  size_t n = 0;
  for (size_t i = 0; i < views.size() && i < poses.size(); ++i)
    for (size_t k = 0; k < views[i].cloud.size(); k += std::max<size_t>(1, stride))
      c += poses[i] * views[i].cloud.points[k].cast<double>(), ++n;
  return n ? Eigen::Vector3d(c / double(n)) : c;
}

Result<double> fit_rms(std::vector<RegistrationView> views, const std::vector<Eigen::Isometry3d>& poses,
                       double voxel_m, RegistrationOptions o) {
  if (poses.size() != views.size()) return fail("fit_rms: one pose per view");
  for (size_t i = 0; i < views.size(); ++i) views[i].initial = poses[i];
  o.max_solver_iterations = 0;
  o.max_rounds_per_level = 1;
  o.voxel_m = {voxel_m};
  o.try_flip = false;
  o.progress = false;
  o.on_round = nullptr;
  auto r = register_views(views, o);
  if (!r) return std::unexpected(r.error());
  return r->rms_m;
}

void add_to_report(const RegistrationResult& r, const std::vector<RegistrationView>& views, Report& report) {
  // Per view and per pair figures go to tables (views.csv, pairs.csv); the
  // report keeps the totals and the worst.
  report.errors["rms_point_to_plane_m"] = r.rms_m;
  report.counts["views"] = double(r.poses.size());
  report.counts["pairs"] = double(r.pairs.size());
  report.counts["iterations"] = r.iterations;
  report.counts["rounds"] = r.rounds;
  int flagged = 0, flipped = 0, held = 0;
  for (const auto& v : r.views) flagged += v.flagged, flipped += v.flipped, held += v.angle_held;
  if (held) report.skipped["view_angles_held_at_table_angle"] = held;
  report.counts["flagged_views"] = flagged;
  report.counts["flipped_views"] = flipped;
  report.params["voxel_schedule_m"] = [&] {
    std::string s;
    for (double v : r.voxel_m) s += (s.empty() ? "" : ", ") + fmt::format("{:.5f}", v);
    return s;
  }();
  double worst_pair = 0, least_overlap = 1, worst_view = 0;
  for (const auto& p : r.pairs) worst_pair = std::max(worst_pair, p.rms_m), least_overlap = std::min(least_overlap, p.overlap);
  for (const auto& v : r.views) worst_view = std::max(worst_view, v.rms_m);
  report.errors["worst_pair_rms_m"] = worst_pair;
  report.errors["worst_view_rms_m"] = worst_view;
  report.counts["least_pair_overlap"] = r.pairs.empty() ? 0 : least_overlap;
  // Every pair in one readable line: "a-b overlap % / RMS mm".
  std::string pairs;
  for (const auto& p : r.pairs)
    pairs += fmt::format("{}{}-{} {:.0f}% {:.3f}mm", pairs.empty() ? "" : ", ", p.a, p.b, 100 * p.overlap, 1e3 * p.rms_m);
  report.params["pairs_overlap_rms"] = pairs;
  std::string flagged_views;
  for (size_t i = 0; i < r.views.size(); ++i)
    if (r.views[i].flagged)
      flagged_views += (flagged_views.empty() ? "" : "; ") + (i < views.size() ? views[i].name : std::to_string(i)) +
                       ": " + r.views[i].note;
  if (!flagged_views.empty()) report.params["flagged_views"] = flagged_views;
  if (r.slide.computed) {
    report.errors["slide_sensitivity"] = r.slide.sensitivity;
    report.errors["slide_sigma_deg"] = r.slide.sigma_deg;
    report.counts["slide_weak_directions"] = r.slide.weak_directions;
    report.params["slide"] = r.slide.description;
  }
  report.warnings.insert(report.warnings.end(), r.warnings.begin(), r.warnings.end());
}

}  // namespace s2r
