// `s2r render` and `s2r eval`: a model drawn offscreen (EGL) at a session
// frame's camera or a view file, and compared with the photos.
//
// Evaluation at a frame (held out at reconstruct or an input view): the
// model is drawn three ways in one run — billboards with depth clipping (the
// product), billboards without it, and the textured patch mesh (the
// baseline) — against the same background: the one asked for, else the
// session's own (a data set's, e.g. white for NeRF-synthetic), else the
// photo's backdrop colour for object-centre sessions, black otherwise. A
// photo with a matte is composited on that background too. Two figures per
// method:
//   - full image, as the field reports novel views (PSNR and SSIM over every
//     pixel, the model drawn on the background);
//   - masked: over the object's pixels (the rig's ground truth, else the
//     session's matte, else the backdrop mask, else the whole image) joined
//     with every pixel any method drew, so drawing onto the background is an
//     error too.
// Frames with a true matte (a data set's alpha) also get each drawing's
// coverage checked against it, over the image and over the silhouette's band.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "core/report.h"
#include "core/result.h"
#include "capture/session.h"
#include "reconstruct/frame_inputs.h"
#include "render/glossy_renderer.h"
#include "render/model_renderer.h"

namespace s2r {

// Where a session frame's camera comes from (reconstruct's own rules:
// reconstruct/frame_inputs.h).
struct FrameSource {
  std::filesystem::path session;
  std::filesystem::path poses;
  std::filesystem::path calibration;
};

// A view file (docs/formats.md "View"): {"format": "s2r.view", "version": 1,
// "intrinsics": {...}, "world_from_camera": 4x4}. Written by the viewer's
// save key, read by `s2r render --pose`. Non-finite values are rejected.
Result<ViewCamera> load_view_file(const std::filesystem::path& path);
Status save_view_file(const std::filesystem::path& path, const ViewCamera& view);

// A session's frame cameras, loaded once: poses by reconstruct's rules,
// intrinsics from the calibration when given, else the session's.
struct SessionCameras {
  Session session;
  FramePoses poses;
  std::optional<Calibration> calibration;
  static Result<SessionCameras> load(const FrameSource& source);
  Result<ViewCamera> view(int frame) const;
};

// The camera of session frame `frame`: the model's own when the frame is one
// of its cameras, else from the session (needs `source.session`).
// `own_capture` (optional): whether the frame is of the capture the model was
// made from (its backdrop plate applies).
Result<ViewCamera> frame_view(const Model& model, const FrameSource& source, int frame, bool* own_capture = nullptr);

struct RenderJob {
  std::filesystem::path model;
  // The image's background (RGB in [0, 1]); empty: the draw options' own.
  std::optional<std::array<float, 3>> background;
  std::filesystem::path out;  // PNG
  std::optional<int> view;    // a session frame
  std::filesystem::path view_file;
  FrameSource source;
  DrawOptions draw;
  double scale = 1;           // image size relative to the view's
  // A frame of the model's own capture drawn on its backdrop plate (where it
  // has one and the image is the photos' size); false: the background colour.
  bool backdrop_plate = true;
  std::optional<EnvironmentSetup> environment;  // backdrop, glossy floor and props

  // The options' own ranges, an error naming the field ("scale: ...").
  Status validate() const;
};
// What run_render_job drew, typed; report.json is to_report().
struct RenderSummary {
  DrawStats draw;               // facets drawn and skipped, triangles, the LOD's counts, ms
  int width = 0, height = 0;
  double texture_mib = 0;       // camera textures held on the GPU
  std::string renderer;         // the OpenGL renderer string
  double seconds = 0;
  Report report;

  const Report& to_report() const { return report; }
  std::string brief() const { return report.brief(); }
};
Result<RenderSummary> run_render_job(const RenderJob& job);

struct EvalJob {
  std::filesystem::path model;
  FrameSource source;
  std::vector<int> frames;
  std::filesystem::path out;  // folder: per-view strips, eval.csv, report.json
  DrawOptions draw;
  bool baselines = true;      // billboards without clipping and the mesh, in the same run
  // The methods to draw (fitted, billboards, hybrid, no_clip, mesh, surface); empty: all of the above that apply.
  std::set<std::string> only;
  std::filesystem::path splats;  // a snapshot of the fit (splats_<S>s.bin) drawn as "fitted" instead of the model's
  // RGB in [0, 1]; empty: the session's background, else the backdrop's colour, else black.
  std::optional<std::array<float, 3>> background;
  // Frames of the model's own capture drawn on its backdrop plate (where it
  // has one); false: on the background colour.
  bool backdrop_plate = true;

  // The options' own needs, an error naming the field ("frames: ...").
  Status validate() const;
};

// One way of drawing the model (billboards, hybrid, no_clip, mesh, surface),
// its figures averaged over the evaluated frames.
struct EvalMethodFigures {
  std::string name;
  double psnr_db = 0, ssim = 0;            // masked: the object's and every drawn pixel
  double full_psnr_db = 0, full_ssim = 0;  // the whole image on the background
  double coverage = 0;                     // share of the object's pixels drawn
  double frame_ms = 0;
  std::optional<double> psnr_db_held_out, psnr_db_input_views;  // masked, over those frames only
  std::optional<double> full_psnr_db_held_out;
  // Frames with a true fractional matte (a data set's alpha): the drawing's
  // coverage against it, mean |alpha - matte| in [0, 1] over the image and
  // over the silhouette's band (the matte's edge and 2 px either side), and
  // the colour's PSNR in that band (where dark or light fringes show).
  std::optional<double> matte_mae, matte_edge_mae, edge_psnr_db;
};

// What run_eval_job measured, typed; report.json adds each frame's figures
// and the billboards' selection counts (to_report()).
struct EvalSummary {
  std::vector<EvalMethodFigures> methods;  // billboards first
  size_t views = 0, held_out_views = 0, facets = 0;
  size_t frames_on_backdrop_plate = 0;  // drawn on the model's backdrop plate
  std::string mask_source;                 // ground_truth, matte, backdrop or whole_image
  std::array<float, 3> background{};       // of the last frame
  double seconds = 0;
  Report report;

  const EvalMethodFigures* method(std::string_view name) const;
  // a's masked PSNR minus b's (over the held-out frames only with `held_out`);
  // empty when either was not drawn (or no frame was held out).
  std::optional<double> gain_db(std::string_view a, std::string_view b, bool held_out = false) const;
  const Report& to_report() const { return report; }
  std::string brief() const { return report.brief(); }
};
Result<EvalSummary> run_eval_job(const EvalJob& job);

// Frame time on a moving view: `frames` frames of width x height around the
// model's default orbit (render/viewer.h), each turned by 360/frames deg.
struct FrameTiming {
  double mean_ms = 0, median_ms = 0;
  double facets_drawn_mean = 0;
  std::vector<double> frame_ms;  // per orbit frame
  std::string renderer;
};
Result<FrameTiming> time_orbit(const std::filesystem::path& model, const DrawOptions& draw, int width, int height,
                               int frames);
// Several settings on one loaded model, interleaved: every orbit frame is
// drawn with each setting in turn, so a burst of other load on a shared
// machine hits them alike and per-frame ratios between settings stay fair.
Result<std::vector<FrameTiming>> time_orbit(const std::filesystem::path& model, const std::vector<DrawOptions>& draws,
                                            int width, int height, int frames);

}  // namespace s2r
