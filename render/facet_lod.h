// Octree level of detail for the billboards (Wakatsuki et al. 2003, with
// the facet error bound of Yamazaki et al. 2002 and the visual field of
// Mochizuki and Makino; docs/references.md). Built once per model from
// its surface octree; run on the CPU every frame before the per-facet camera
// choice (render/facet_selection.h).
//
// Every model facet belongs to the deepest octree node whose cells contain
// its centre (facets outside the tree, e.g. fuzzy evidence far from any
// surface crossing, are "loose" and always go to the per-facet tests). A node
// holding two or more facets also gets a *node billboard*: centred at its
// representative vertex v, wide enough to cover every facet below it from any
// direction (radius r = max |c_i - v| + sqrt(3)/2 w_i, so its width w_n =
// 2r/sqrt(3) keeps the billboard rule width >= sqrt(3) w_n and the clip
// tolerance sqrt(3)/2 w_n = r), seen by every camera that sees one of its
// facets, with its normal cone's axis as normal (none when the cone is wider
// than pi/2).
//
// Selection from the root, per node (Wakatsuki et al. 2003, section 3.5):
//   1. frustum: the node's sphere (v, r) outside the view -> skipped;
//   2. normal cone: gamma = angle(v_e, n); the whole cone faces away
//      (gamma - theta - asin(r/d_o) beyond the per-facet back-face angle,
//      with a 10 deg margin for facet normals that differ from the cone's)
//      -> skipped, "back-facing" for every facet below;
//   3. visual field (optional, around a gaze pixel): level 0 at the node's
//      point nearest the gaze -> skipped; a level l in (0, 1] divides the
//      three thresholds below by l (coarser in the periphery);
//   4. accept the node billboard when all hold, else draw the node's own
//      facets and recurse into the children:
//      - contour (pi/2 - theta <= gamma): dE / d_o <= T_s / d_s (eq. 4-5);
//      - luminance: dB l_s <= T_b with l_s = d_s l_p (n . v_e) / d_o (eq. 9-10),
//        l_p the node's cube side. The paper's dB comes from lights and a
//        Phong model (eq. 6-8); here the surfaces carry photographs, so dB
//        is the measured luminance range (0..1) of the node's facets in
//        their most head-on cameras: the contrast a coarse node would smear;
//      - texel bound (§6): a texel of a surface point within s of the
//        billboard's centre, taken from a camera at angle alpha to the view,
//        lands at most s sin(alpha) from where it belongs; with s the node's
//        surface radius (max |c_i - v| + w_i/2) and alpha the angle of the
//        node's best camera, s sin(alpha) d_s / d_o <= T_e pixels.
// d_s is the view's focal length in pixels, d_o the distance to v.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "reconstruct/model.h"

namespace s2r {

struct ViewCamera;

struct LodOptions {
  bool enabled = false;
  double shape_px = 0.5;    // T_s: contour shape error on screen, pixels (the paper's 0.5)
  double luminance = 1.5;   // T_b: luminance range (0..1) x projected side (pixels) (the paper's 1.5)
  double texel_px = 1.0;    // T_e: the §6 texel misplacement bound on screen, pixels
  bool field = false;       // visual-field LOD around gaze_px
  std::optional<Eigen::Vector2d> gaze_px;  // default: the image centre
  double backface_cos = -0.25;  // as SelectionOptions::backface_cos
};

struct LodStats {
  size_t nodes_visited = 0;
  size_t node_billboards = 0;        // coarse billboards drawn
  size_t facets_replaced = 0;        // model facets they stand for
  size_t facets_back_cone = 0;       // culled with their node by its normal cone
  size_t facets_outside_frustum = 0; // culled with their node by its sphere
  size_t facets_outside_field = 0;   // visual-field level 0
  size_t refined_contour = 0, refined_luminance = 0, refined_texel = 0;  // nodes each test sent down
  size_t loose_facets = 0;           // outside the octree: per-facet tests only
  double seconds = 0;
};

class FacetHierarchy {
 public:
  // `facet_luminance`: per model facet, 0..1 (empty: no luminance test).
  // A model without an octree gives an empty hierarchy.
  static FacetHierarchy build(const Model& model, const std::vector<float>& facet_luminance = {});

  bool empty() const { return nodes_.empty(); }
  size_t node_billboards() const { return facets_.size() - model_facets_; }
  // The model's facets, then the node billboards; their camera lists.
  const std::vector<FacetRecord>& facets() const { return facets_; }
  const std::vector<uint32_t>& facet_cameras() const { return facet_cameras_; }
  // Per entry of facets(): the least reliability of the model facets it
  // stands for (a model facet: its own). Where the patch mesh is drawn for
  // reliable geometry, an entry at or above the threshold is left to it.
  const std::vector<float>& least_reliability() const { return least_reliability_; }

  // Indices into facets() for this view (with LOD off: every model facet).
  LodStats select(const ViewCamera& view, const LodOptions& options, double near_m, std::vector<uint32_t>& out) const;

 private:
  struct Node {
    int32_t first_child = -1;
    uint8_t children = 0;
    uint32_t begin = 0, own_end = 0, end = 0;  // range in order_: own facets, then the children's
    int32_t billboard = -1;                    // index in facets_
    Eigen::Vector3f vertex = Eigen::Vector3f::Zero(), normal = Eigen::Vector3f::Zero();
    float cone = 0, shape_error = 0, side = 0;
    float radius = 0;          // covers every facet below
    float surface_radius = 0;  // the texel bound's s
    float luminance_range = 0;
  };
  struct Frame;
  void visit(int node, const Frame& f, std::vector<uint32_t>& out, LodStats& st) const;
  void emit_own(const Node& n, std::vector<uint32_t>& out) const;

  size_t model_facets_ = 0;
  std::vector<Node> nodes_;
  std::vector<uint32_t> order_;  // model facet indices, node by node in pre-order
  std::vector<uint32_t> loose_;
  std::vector<FacetRecord> facets_;
  std::vector<uint32_t> facet_cameras_;
  std::vector<float> least_reliability_;
  std::vector<Eigen::Vector3f> camera_centres_;
};

}  // namespace s2r
