// A first look at a session: every frame's depth back-projected as coloured
// points in the world (with given or ground-truth poses), drawn offscreen from
// one view's camera, and compared with that view's photo.
#pragma once

#include <filesystem>
#include <optional>

#include "capture/session.h"
#include "core/image.h"
#include "core/report.h"
#include "core/result.h"
#include "render/gl_context.h"

namespace s2r {

struct PreviewOptions {
  int view = 0;           // whose camera draws the image
  float point_size = 0;   // pixels; 0 = from the depth sampling
  int stride = 1;         // depth pixels: take every n-th row/column
  bool single_view = false;  // only view `view`'s own depth
};

struct Preview {
  ImageU8 image;
  ImageU8 coverage;  // 255 where points were drawn
  Report report;
};

// Uses `context` (headless or a window): the same drawing either way.
Result<Preview> render_session_preview(GlContext& context, const Session& session, const PreviewOptions& options);

// `s2r preview`: headless context, writes OUT (png) and OUT's *_compare.png.
Result<Report> preview_to_file(const std::filesystem::path& session_dir, const PreviewOptions& options,
                               const std::filesystem::path& out_png);

}  // namespace s2r
