// Exports of a calibrated capture: COLMAP's text model and nerfstudio's
// transforms.json (reconstruct/session_export.h).
#include "reconstruct/session_export.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <unordered_map>

#include <nlohmann/json.hpp>

#include "calibrate/calibration.h"
#include "capture/session.h"
#include "core/atomic_file.h"
#include "core/progress.h"
#include "core/rgbd.h"
#include "reconstruct/frame_inputs.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

struct Usable {
  const Frame* frame;
  Eigen::Isometry3d world_from_camera;
  Intrinsics K;
  std::string image;  // file name in images/
};

std::string frame_name(const Frame& f, const std::string& ext) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d", f.index);
  return buf + ext;
}

std::string fmt(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

Status copy_into(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::create_directories(to.parent_path(), ec);
  if (!fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec))
    return fail(ErrorCode::io, "copying " + from.string() + " to " + to.string() + ": " + ec.message());
  return {};
}

Status write_text(const fs::path& path, const std::string& text) { return write_file_atomic(path, text); }

// COLMAP's camera model and parameters for an Intrinsics (pixel centres at
// i + 0.5 in COLMAP, at i here).
std::pair<std::string, std::vector<double>> colmap_camera(const Intrinsics& K) {
  const double cx = K.cx + 0.5, cy = K.cy + 0.5;
  const auto& d = K.dist;
  if (!K.has_distortion()) return {"PINHOLE", {K.fx, K.fy, cx, cy}};
  if (d[4] == 0) return {"OPENCV", {K.fx, K.fy, cx, cy, d[0], d[1], d[2], d[3]}};
  return {"FULL_OPENCV", {K.fx, K.fy, cx, cy, d[0], d[1], d[2], d[3], d[4], 0, 0, 0}};
}

struct Voxel {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero(), sum_sq = Eigen::Vector3d::Zero();
  Eigen::Vector3d color = Eigen::Vector3d::Zero();
  int count = 0;
  std::vector<int> frames;  // indices into the usable frames, ascending
};

struct Key {
  int x, y, z;
  bool operator==(const Key& o) const { return x == o.x && y == o.y && z == o.z; }
};
struct KeyHash {
  size_t operator()(const Key& k) const {
    return (static_cast<size_t>(k.x) * 73856093u) ^ (static_cast<size_t>(k.y) * 19349663u) ^
           (static_cast<size_t>(k.z) * 83492791u);
  }
};

Status write_colmap(const Session& s, const std::vector<Usable>& frames, const ExportJob& job, const fs::path& dir,
                    Report& rep) {
  // Cameras: one per distinct intrinsics.
  std::vector<std::pair<std::string, std::vector<double>>> cams;
  std::vector<std::pair<int, int>> sizes;
  std::vector<int> camera_of(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    auto c = colmap_camera(frames[i].K);
    const std::pair<int, int> wh{frames[i].K.width, frames[i].K.height};
    size_t k = 0;
    while (k < cams.size() && !(cams[k] == c && sizes[k] == wh)) ++k;
    if (k == cams.size()) {
      cams.push_back(c);
      sizes.push_back(wh);
    }
    camera_of[i] = static_cast<int>(k) + 1;
  }
  std::ostringstream ct;
  ct << "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
     << "# Number of cameras: " << cams.size() << "\n";
  for (size_t k = 0; k < cams.size(); ++k) {
    ct << k + 1 << " " << cams[k].first << " " << sizes[k].first << " " << sizes[k].second;
    for (double v : cams[k].second) ct << " " << fmt(v);
    ct << "\n";
  }

  // Points: the depth frames fused on a voxel grid.
  std::vector<Eigen::Vector3d> point_pos;
  std::vector<std::array<int, 3>> point_rgb;
  std::vector<double> point_err;
  std::vector<std::vector<int>> point_frames;
  const DepthSensorModel ds = resolve_depth_sensor(s, nullptr);
  if (ds.intrinsics) {
    Calibration cal;
    const Calibration* calp = nullptr;
    if (!job.calibration.empty()) {
      auto c = load_calibration(job.calibration);
      if (!c) return std::unexpected(c.error());
      cal = *c;
      calp = &cal;
    }
    const DepthSensorModel d = resolve_depth_sensor(s, calp);
    struct Sample {
      Eigen::Vector3d p;
      std::array<uint8_t, 3> c;
      int frame;
    };
    std::vector<Sample> samples;
    std::vector<std::optional<ImageU16>> depths(frames.size());
    Progress progress("export points", frames.size());
    for (size_t i = 0; i < frames.size(); ++i) {
      progress.tick();
      const Frame& f = *frames[i].frame;
      if (f.depth.empty()) continue;
      auto depth = load_depth(s, f);
      if (!depth) return std::unexpected(depth.error());
      auto color = load_color(s, f);
      if (!color) return std::unexpected(color.error());
      const ColoredPoints pts = depth_to_points(*depth, d.unit_m, *d.intrinsics, d.color_from_depth, &*color,
                                                &frames[i].K, 2);
      for (size_t k = 0; k < pts.points.size(); ++k)
        samples.push_back({frames[i].world_from_camera * pts.points[k].cast<double>(), pts.colors[k], static_cast<int>(i)});
      depths[i] = std::move(*depth);
    }
    // A frame sees a point when its depth at the point's pixel agrees with the
    // point's distance (within 1 % and two grid cells).
    const Eigen::Isometry3d depth_from_color = d.color_from_depth.inverse();
    auto sees = [&](size_t i, const Eigen::Vector3d& world, double voxel) {
      if (!depths[i]) return false;
      const Eigen::Vector3d pd = depth_from_color * (frames[i].world_from_camera.inverse() * world);
      if (pd.z() <= 0) return false;
      auto px = d.intrinsics->project(pd);
      if (!px) return false;
      const int u = static_cast<int>(std::lround(px->x())), v = static_cast<int>(std::lround(px->y()));
      const ImageU16& img = *depths[i];
      if (u < 0 || v < 0 || u >= img.width || v >= img.height) return false;
      const uint16_t raw = img.at(u, v);
      if (raw == 0) return false;
      return std::abs(raw * d.unit_m - pd.z()) <= std::max(0.01 * pd.z(), 2 * voxel);
    };
    if (!samples.empty()) {
      Eigen::Vector3d lo = samples[0].p, hi = samples[0].p;
      for (const auto& q : samples) {
        lo = lo.cwiseMin(q.p);
        hi = hi.cwiseMax(q.p);
      }
      const double voxel = job.point_voxel_m > 0 ? job.point_voxel_m : std::max(1e-4, (hi - lo).maxCoeff() / 256);
      rep.params["point_voxel_m"] = voxel;
      std::unordered_map<Key, Voxel, KeyHash> grid;
      for (const auto& q : samples) {
        const Key k{static_cast<int>(std::floor(q.p.x() / voxel)), static_cast<int>(std::floor(q.p.y() / voxel)),
                    static_cast<int>(std::floor(q.p.z() / voxel))};
        Voxel& v = grid[k];
        v.sum += q.p;
        v.sum_sq += q.p.cwiseProduct(q.p);
        v.color += Eigen::Vector3d(q.c[0], q.c[1], q.c[2]);
        ++v.count;
        if (v.frames.empty() || v.frames.back() != q.frame) v.frames.push_back(q.frame);
      }
      std::vector<const Voxel*> order;
      for (const auto& [k, v] : grid) order.push_back(&v);
      std::sort(order.begin(), order.end(), [](const Voxel* a, const Voxel* b) {
        if (a->frames.size() != b->frames.size()) return a->frames.size() > b->frames.size();
        if (a->count != b->count) return a->count > b->count;
        return std::lexicographical_compare(a->sum.data(), a->sum.data() + 3, b->sum.data(), b->sum.data() + 3);
      });
      if (static_cast<int>(order.size()) > job.max_points) {
        rep.skipped["points_over_max_points"] = static_cast<double>(order.size() - job.max_points);
        order.resize(job.max_points);
      }
      for (const Voxel* v : order) {
        const Eigen::Vector3d mean = v->sum / v->count;
        const Eigen::Vector3d var = (v->sum_sq / v->count - mean.cwiseProduct(mean)).cwiseMax(0.0);
        const Eigen::Vector3d c = v->color / v->count;
        point_pos.push_back(mean);
        point_rgb.push_back({static_cast<int>(std::lround(c.x())), static_cast<int>(std::lround(c.y())),
                             static_cast<int>(std::lround(c.z()))});
        // The spread of the samples merged into the point, in pixels of its
        // first camera: COLMAP's per-point error.
        const Usable& u = frames[v->frames.front()];
        const double z = std::max(1e-6, (u.world_from_camera.inverse() * mean).z());
        point_err.push_back(std::sqrt(var.sum()) * u.K.fx / z);
        std::vector<int> seen_by;
        for (size_t i = 0; i < frames.size(); ++i)
          if (std::binary_search(v->frames.begin(), v->frames.end(), static_cast<int>(i)) || sees(i, mean, voxel))
            seen_by.push_back(static_cast<int>(i));
        point_frames.push_back(std::move(seen_by));
      }
    }
  } else {
    rep.skipped["points_no_depth"] = 1;
  }

  // Observations: each point projected into the frames that saw it.
  std::vector<std::vector<std::pair<Eigen::Vector2d, int>>> obs(frames.size());  // per image: (xy, point id)
  std::vector<std::vector<std::pair<int, int>>> tracks(point_pos.size());        // per point: (image id, idx)
  size_t observations = 0;
  for (size_t p = 0; p < point_pos.size(); ++p) {
    for (int fi : point_frames[p]) {
      const Usable& u = frames[fi];
      const Eigen::Vector3d pc = u.world_from_camera.inverse() * point_pos[p];
      auto px = u.K.project(pc);
      if (!px || px->x() < -0.5 || px->y() < -0.5 || px->x() > u.K.width - 0.5 || px->y() > u.K.height - 0.5) continue;
      tracks[p].push_back({fi + 1, static_cast<int>(obs[fi].size())});
      obs[fi].push_back({*px + Eigen::Vector2d(0.5, 0.5), static_cast<int>(p) + 1});
      ++observations;
    }
  }
  std::ostringstream it;
  it << "# Image list with two lines of data per image:\n"
     << "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
     << "# Number of images: " << frames.size() << "\n";
  for (size_t i = 0; i < frames.size(); ++i) {
    const Eigen::Isometry3d cw = frames[i].world_from_camera.inverse();
    Eigen::Quaterniond q(cw.rotation());
    q.normalize();
    if (q.w() < 0) q.coeffs() *= -1;
    const Eigen::Vector3d t = cw.translation();
    it << i + 1 << " " << fmt(q.w()) << " " << fmt(q.x()) << " " << fmt(q.y()) << " " << fmt(q.z()) << " " << fmt(t.x())
       << " " << fmt(t.y()) << " " << fmt(t.z()) << " " << camera_of[i] << " " << frames[i].image << "\n";
    for (size_t k = 0; k < obs[i].size(); ++k)
      it << (k ? " " : "") << fmt(obs[i][k].first.x()) << " " << fmt(obs[i][k].first.y()) << " " << obs[i][k].second;
    it << "\n";
  }
  std::ostringstream pt;
  pt << "# 3D point list with one line of data per point:\n"
     << "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
     << "# Number of points: " << point_pos.size() << "\n";
  for (size_t p = 0; p < point_pos.size(); ++p) {
    pt << p + 1 << " " << fmt(point_pos[p].x()) << " " << fmt(point_pos[p].y()) << " " << fmt(point_pos[p].z()) << " "
       << point_rgb[p][0] << " " << point_rgb[p][1] << " " << point_rgb[p][2] << " " << fmt(point_err[p]);
    for (const auto& [img, idx] : tracks[p]) pt << " " << img << " " << idx;
    pt << "\n";
  }
  if (auto st = write_text(dir / "cameras.txt", ct.str()); !st) return st;
  if (auto st = write_text(dir / "images.txt", it.str()); !st) return st;
  if (auto st = write_text(dir / "points3D.txt", pt.str()); !st) return st;
  rep.counts["cameras"] = static_cast<double>(cams.size());
  rep.counts["points"] = static_cast<double>(point_pos.size());
  rep.counts["observations"] = static_cast<double>(observations);
  return {};
}

Status write_nerfstudio(const Session& s, const std::vector<Usable>& frames, const fs::path& dir, Report& rep) {
  json out;
  out["camera_model"] = "OPENCV";
  out["s2r_session"] = s.name;
  json list = json::array();
  int masks = 0;
  Eigen::Matrix4d gl_from_cv = Eigen::Matrix4d::Identity();
  gl_from_cv(1, 1) = -1;
  gl_from_cv(2, 2) = -1;
  for (const auto& u : frames) {
    const Eigen::Matrix4d c2w = u.world_from_camera.matrix() * gl_from_cv;
    json m = json::array();
    for (int r = 0; r < 4; ++r) m.push_back({c2w(r, 0), c2w(r, 1), c2w(r, 2), c2w(r, 3)});
    json f = {{"file_path", "images/" + u.image},
              {"transform_matrix", m},
              {"fl_x", u.K.fx},
              {"fl_y", u.K.fy},
              {"cx", u.K.cx + 0.5},
              {"cy", u.K.cy + 0.5},
              {"w", u.K.width},
              {"h", u.K.height},
              {"k1", u.K.dist[0]},
              {"k2", u.K.dist[1]},
              {"p1", u.K.dist[2]},
              {"p2", u.K.dist[3]}};
    if (u.K.dist[4] != 0) f["k3"] = u.K.dist[4];
    if (!u.frame->mask.empty()) {
      const std::string name = "masks/" + frame_name(*u.frame, fs::path(u.frame->mask).extension().string());
      if (auto st = copy_into(s.path_of(u.frame->mask), dir / name); !st) return st;
      f["mask_path"] = name;
      ++masks;
    }
    list.push_back(std::move(f));
  }
  out["frames"] = std::move(list);
  rep.counts["masks"] = masks;
  return write_text(dir / "transforms.json", out.dump(2) + "\n");
}

}  // namespace

Result<Report> export_session(const ExportJob& job) {
  Stopwatch sw;
  Report rep;
  rep.stage = "export";
  rep.params["format"] = job.format;
  if (job.format != "colmap" && job.format != "nerfstudio")
    return fail(ErrorCode::invalid, "format: '" + job.format + "' (choose colmap or nerfstudio)");
  if (job.max_points < 0) return fail(ErrorCode::invalid, "max_points: must be >= 0");
  if (auto st = check_new_folder(job.out); !st) return std::unexpected(st.error());
  auto s = load_session(job.session);
  if (!s) return fail_with_context(s.error(), "session");
  auto poses = resolve_frame_poses(*s, job.poses, job.calibration);
  if (!poses) return fail_with_context(poses.error(), "poses");
  Calibration cal;
  const Calibration* calp = nullptr;
  if (!job.calibration.empty()) {
    auto c = load_calibration(job.calibration);
    if (!c) return fail_with_context(c.error(), "calibration");
    cal = *c;
    calp = &cal;
  }
  rep.params["poses"] = poses->source;
  std::vector<Usable> frames;
  for (size_t i = 0; i < s->frames.size(); ++i) {
    const Frame& f = s->frames[i];
    if (f.color.empty()) {
      rep.skipped["frames_without_colour"] += 1;
      continue;
    }
    if (!poses->world_from_camera[i]) {
      rep.skipped["frames_without_pose"] += 1;
      continue;
    }
    auto K = resolve_color_intrinsics(*s, f, calp);
    if (!K) {
      rep.skipped["frames_without_intrinsics"] += 1;
      continue;
    }
    frames.push_back({&f, *poses->world_from_camera[i], *K, frame_name(f, fs::path(f.color).extension().string())});
  }
  if (frames.empty())
    return fail(ErrorCode::invalid, "session '" + job.session.string() + "': no frame has a colour image, a pose and intrinsics");

  auto written = write_folder_atomic(job.out, [&](const fs::path& tmp) -> Status {
    for (const auto& u : frames)
      if (auto st = copy_into(s->path_of(u.frame->color), tmp / "images" / u.image); !st) return st;
    auto st = job.format == "colmap" ? write_colmap(*s, frames, job, tmp, rep) : write_nerfstudio(*s, frames, tmp, rep);
    if (!st) return st;
    rep.counts["frames"] = static_cast<double>(frames.size());
    rep.seconds = sw.seconds();
    return rep.write(tmp / "report.json");
  });
  if (!written) return std::unexpected(written.error());
  return rep;
}

}  // namespace s2r
