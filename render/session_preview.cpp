#include "render/session_preview.h"

#include <epoxy/gl.h>

#include <cmath>

#include "core/image_io.h"
#include "core/image_metrics.h"
#include "core/mesh.h"
#include "core/rgbd.h"
#include "reconstruct/frame_inputs.h"
#include "render/framebuffer.h"
#include "render/gl_camera.h"
#include "render/point_renderer.h"

namespace s2r {

Result<Preview> render_session_preview(GlContext& context, const Session& s, const PreviewOptions& o) {
  Stopwatch clock;
  if (s.frames.empty()) return fail("session '" + s.root.string() + "' has no frames");
  if (o.view < 0 || o.view >= static_cast<int>(s.frames.size()))
    return fail(ErrorCode::invalid, "view: " + std::to_string(o.view) + " is not a frame of this session (0.." +
                std::to_string(s.frames.size() - 1) + ")");
  const Frame& target = s.frames[size_t(o.view)];
  auto K = resolve_color_intrinsics(s, target, nullptr);
  if (!K && s.depth) K = s.depth->intrinsics;
  if (!K) return fail("view " + std::to_string(o.view) + " has no camera intrinsics");

  // Poses by reconstruct's rules (given, else the rig's ground truth); a
  // session with neither is drawn from the chosen view alone.
  std::vector<std::optional<Eigen::Isometry3d>> poses(s.frames.size());
  std::string pose_source;
  if (auto fp = resolve_frame_poses(s, {}, {})) {
    poses = std::move(fp->world_from_camera);
    pose_source = fp->kind == PoseSource::ground_truth ? "ground_truth" : "given";
  } else {
    poses[size_t(o.view)] = Eigen::Isometry3d::Identity();
    pose_source = "single_view";
  }

  Preview out;
  Report& rep = out.report;
  rep.stage = "preview";
  std::vector<Eigen::Vector3f> points;
  std::vector<std::array<uint8_t, 3>> colors;
  int used = 0;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    const Frame& f = s.frames[i];
    if (o.single_view && static_cast<int>(i) != o.view) continue;
    if (!poses[i]) {
      rep.skipped["frame_without_pose"] += 1;
      continue;
    }
    const Eigen::Isometry3f world_from_camera = poses[i]->cast<float>();
    if (!f.depth.empty() && s.depth) {
      auto depth = load_depth(s, f);
      if (!depth) return std::unexpected(depth.error());
      std::optional<ImageU8> color;
      if (!f.color.empty()) {
        auto c = load_color(s, f);
        if (!c) return std::unexpected(c.error());
        color = std::move(*c);
      }
      auto Kc = s.color_intrinsics(f);
      const Eigen::Isometry3d cfd = s.depth->aligned_to_color ? Eigen::Isometry3d::Identity() : s.depth->color_from_depth;
      ColoredPoints cp = depth_to_points(*depth, s.depth->unit_m, s.depth->intrinsics, cfd,
                                         color ? &*color : nullptr, Kc ? &*Kc : nullptr, o.stride);
      for (size_t k = 0; k < cp.points.size(); ++k) {
        points.push_back(world_from_camera * cp.points[k]);
        colors.push_back(cp.colors[k]);
      }
      ++used;
    } else if (!f.points.empty()) {
      auto scan = read_ply_points(s.path_of(f.points));
      if (!scan) return std::unexpected(scan.error());
      for (size_t k = 0; k < scan->points.size(); k += size_t(std::max(1, o.stride))) {
        points.push_back(world_from_camera * scan->points[k]);
        const uint8_t g = static_cast<uint8_t>(90 + 40 * (i % 4));
        colors.push_back({g, g, static_cast<uint8_t>(g + 20)});
      }
      ++used;
    } else {
      rep.skipped["frame_without_geometry"] += 1;
    }
  }
  if (points.empty()) return fail("nothing to draw: no frame has depth or points with a known pose");

  context.make_current();
  auto fb = Framebuffer::create(K->width, K->height);
  if (!fb) return std::unexpected(fb.error());
  auto renderer = PointRenderer::create();
  if (!renderer) return std::unexpected(renderer.error());
  // Near/far from the points' depths in the target camera.
  const Eigen::Isometry3f camera_from_world = poses[size_t(o.view)]->inverse().cast<float>();
  float zmin = 1e30f, zmax = 0;
  for (const auto& p : points) {
    const float z = (camera_from_world * p).z();
    if (z > 0) { zmin = std::min(zmin, z); zmax = std::max(zmax, z); }
  }
  if (zmax <= 0) { zmin = 0.01f; zmax = 10.f; }
  const float near_m = std::max(1e-3f, 0.5f * zmin), far_m = 2.f * zmax + 0.01f;
  const Eigen::Matrix4f clip = gl_view_projection(*K, *poses[size_t(o.view)], near_m, far_m);
  const float size = o.point_size > 0 ? o.point_size : 1.f + static_cast<float>(std::max(1, o.stride));

  renderer->upload(points, colors);
  fb->clear(0.f, 0.f, 0.f);
  renderer->draw(clip, size);
  out.image = fb->read_rgb();
  // Coverage: the same points in white.
  std::vector<std::array<uint8_t, 3>> white(points.size(), {255, 255, 255});
  renderer->upload(points, white);
  fb->clear(0.f, 0.f, 0.f);
  renderer->draw(clip, size);
  ImageU8 cov = fb->read_rgb();
  out.coverage = ImageU8(cov.width, cov.height, 1);
  size_t covered = 0;
  for (size_t p = 0; p < cov.pixels(); ++p) {
    out.coverage.data[p] = cov.data[3 * p];
    covered += cov.data[3 * p] != 0;
  }

  rep.counts["points"] = double(points.size());
  rep.counts["frames_used"] = used;
  rep.counts["pixels_covered"] = double(covered);
  rep.params["view"] = double(o.view);
  rep.params["poses"] = pose_source;
  rep.params["gl"] = context.describe();
  if (!target.color.empty() && covered > 0) {
    auto photo = load_color(s, target);
    if (!photo) return std::unexpected(photo.error());
    if (photo->width == out.image.width && photo->height == out.image.height) {
      if (auto p = psnr(*photo, out.image, &out.coverage)) rep.errors["psnr_db_vs_photo"] = *p;
      if (auto q = ssim(*photo, out.image, &out.coverage)) rep.errors["ssim_vs_photo"] = *q;
    }
  }
  rep.seconds = clock.seconds();
  return out;
}

Result<Report> preview_to_file(const std::filesystem::path& dir, const PreviewOptions& o,
                               const std::filesystem::path& out_png) {
  auto session = load_session(dir);
  if (!session) return std::unexpected(session.error());
  auto ctx = create_headless_context();
  if (!ctx) return std::unexpected(ctx.error());
  auto pv = render_session_preview(**ctx, *session, o);
  if (!pv) return std::unexpected(pv.error());
  if (auto st = write_image(out_png, pv->image); !st) return std::unexpected(st.error());
  const Frame& f = session->frames[size_t(o.view)];
  if (!f.color.empty()) {  // photo | render, side by side
    if (auto photo = load_color(*session, f); photo && photo->height == pv->image.height) {
      ImageU8 both(photo->width + pv->image.width, photo->height, 3);
      for (int y = 0; y < both.height; ++y)
        for (int x = 0; x < both.width; ++x)
          for (int c = 0; c < 3; ++c)
            both.at(x, y, c) = x < photo->width ? photo->at(x, y, photo->channels >= 3 ? c : 0)
                                                : pv->image.at(x - photo->width, y, c);
      auto cmp = out_png.parent_path() / (out_png.stem().string() + "_compare.png");
      if (auto st = write_image(cmp, both); !st) return std::unexpected(st.error());
    }
  }
  return pv->report;
}

}  // namespace s2r
