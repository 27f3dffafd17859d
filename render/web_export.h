// s2r export web MODEL --out DIR: a static folder that draws the model's
// microfacet billboards with depth clipping in WebGL2 (render/web/viewer.js,
// a port of ModelRenderer's billboard pass and of select_facets), with orbit,
// zoom, pan and touch, a progress bar while it loads and the capture's
// cameras to jump between. No build step, nothing fetched from elsewhere:
//
//   DIR/index.html, DIR/viewer.js   the page (embedded in s2r at build time)
//   DIR/model.json                  `s2r.web` version 1: facets, bounds, up,
//                                   background, drawing options, cameras
//                                   (pose, intrinsics, texture layer), payloads
//   DIR/facets.bin                  the model's FacetRecord[] (40 bytes each)
//   DIR/facet_cameras.bin           uint32[]
//   DIR/colour.bin, distance.bin    every textured camera's RGBA8 image and
//                                   float32 distances (one pixel of silhouette
//                                   extension, as s2r render loads them), each
//                                   layer W x H of the largest camera, the
//                                   image in its top-left corner; reduced by
//                                   an integer factor where they exceed the
//                                   budget
//
// Written into a temporary folder beside DIR and renamed into place whole;
// DIR must be new or empty.
#pragma once

#include <array>
#include <filesystem>
#include <optional>

#include "core/report.h"
#include "core/result.h"

namespace s2r {

struct WebExportJob {
  std::filesystem::path model, out;
  // RGB in [0, 1]; empty: the model's own background, else black.
  std::optional<std::array<float, 3>> background;
  // The camera images' payload at most (colour and distances, 8 bytes a
  // pixel): above it every camera image is reduced by the smallest integer
  // factor that fits (colour averaged over each block, distance the nearest
  // surface in it), its intrinsics scaled to match. The default keeps a
  // 200-photo 12-MP capture under the model's own 2-GiB budget.
  double budget_mib = 1536;
  int threads = 0;
};

Result<Report> export_web(const WebExportJob& job);

// The page's files, as built into this program.
const char* web_index_html();
const char* web_viewer_js();

}  // namespace s2r
