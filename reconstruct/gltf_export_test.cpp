// s2r export gltf (reconstruct/gltf_export.h) checked by others' tools: the
// Khronos glTF-Validator (npm gltf-validator, run by Node: no errors, no
// warnings) and Open3D's reader (Debian's python3-open3d: the triangles, the
// texture and the bounds read back); bad input is a clear error writing
// nothing.
#include "reconstruct/gltf_export.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "capture/synth_rig.h"
#include "core/progress.h"
#include "core/shell.h"
#include "reconstruct/model.h"
#include "reconstruct/reconstruct_job.h"

namespace {
namespace fs = std::filesystem;
using namespace s2r;

std::string run(const std::string& cmd, int* code) {
  const ShellRun r = run_shell(cmd + " 2>&1");
  *code = r.code;
  return r.output;
}

class Gltf : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    set_progress_enabled(false);
    root_ = new fs::path(fs::temp_directory_path() / ("s2r_gltf_" + std::to_string(::getpid())));
    fs::remove_all(*root_);
    SynthOptions o;
    o.scene = "blob";
    o.views = 8;
    o.width = 160;
    o.height = 120;
    ASSERT_TRUE(synth_session(o, *root_ / "session"));
    ReconstructJob job;
    job.session = *root_ / "session";
    job.out = *root_ / "model";
    auto r = run_reconstruct_job(job);
    ASSERT_TRUE(r) << r.error().message;
  }
  static void TearDownTestSuite() {
    fs::remove_all(*root_);
    delete root_;
  }
  static fs::path* root_;
};
fs::path* Gltf::root_ = nullptr;

TEST_F(Gltf, TheValidatorFindsNoErrorOrWarningAndOpen3dReadsItBack) {
  GltfExportJob job;
  job.model = *root_ / "model";
  job.out = *root_ / "blob.glb";
  auto r = export_gltf(job);
  ASSERT_TRUE(r) << r.error().message;
  const int triangles = static_cast<int>(r->counts.at("triangles"));
  EXPECT_GT(triangles, 100);
  EXPECT_EQ(r->counts.at("cameras"), 8);
  // Most texels are seen by a camera (a ring of 8 views leaves the underside).
  EXPECT_LT(r->skipped.at("texels_seen_by_no_camera"), 0.35 * r->counts.at("texels"));
  const int w = static_cast<int>(r->counts.at("atlas_width"));
  EXPECT_EQ(w & (w - 1), 0) << "atlas width " << w << " is not a power of two";

  int code = 0;
  const std::string validator = std::string(S2R_SOURCE_DIR) + "/tools/node/validate_gltf.mjs";
  if (run("command -v node", &code).empty() || code != 0) GTEST_SKIP() << "node not installed (scripts/setup installs nodejs)";
  if (!fs::exists(std::string(S2R_SOURCE_DIR) + "/tools/node/node_modules/gltf-validator"))
    GTEST_SKIP() << "gltf-validator not installed (scripts/setup: npm ci --prefix tools/node)";
  const std::string report = run("node " + validator + " " + job.out.string(), &code);
  EXPECT_EQ(code, 0) << report;
  EXPECT_NE(report.find("\"errors\": 0"), std::string::npos) << report;
  EXPECT_NE(report.find("\"warnings\": 0"), std::string::npos) << report;
  EXPECT_NE(report.find("\"triangles\": " + std::to_string(triangles)), std::string::npos) << report;

  // A second reader: Open3D (Assimp underneath), Debian's build.
  if (run("/usr/bin/python3 -c 'import open3d'", &code), code != 0) GTEST_SKIP() << "python3-open3d not installed";
  auto model = load_model(*root_ / "model");
  ASSERT_TRUE(model);
  const std::string script =
      "import open3d as o3d, numpy as np\n"
      "m = o3d.io.read_triangle_model('" + job.out.string() + "')\n"
      "mesh = m.meshes[0].mesh\n"
      "b = mesh.get_axis_aligned_bounding_box()\n"
      "img = np.asarray(m.materials[m.meshes[0].material_idx].albedo_img)\n"
      "print('triangles', len(mesh.triangles), 'uvs', len(mesh.triangle_uvs), 'texture', img.shape[1], img.shape[0],\n"
      "      'mean', round(float(img.mean()), 1), 'min', *np.round(b.min_bound, 5), 'max', *np.round(b.max_bound, 5))\n";
  std::ofstream(*root_ / "read.py") << script;
  const std::string out = run("/usr/bin/python3 " + (*root_ / "read.py").string(), &code);
  ASSERT_EQ(code, 0) << out;
  std::istringstream in(out.substr(out.find("triangles")));
  std::string word;
  int tris = 0, uvs = 0, tw = 0, th = 0;
  double mean = 0, lo[3], hi[3];
  in >> word >> tris >> word >> uvs >> word >> tw >> th >> word >> mean >> word >> lo[0] >> lo[1] >> lo[2] >> word >> hi[0] >>
      hi[1] >> hi[2];
  EXPECT_EQ(tris, triangles) << out;
  EXPECT_EQ(uvs, 3 * triangles) << out;
  EXPECT_EQ(tw, w) << out;
  EXPECT_GT(mean, 10) << "a black texture: " << out;
  // +Y up: the model's z extent is glTF's y extent, its y is glTF's -z.
  const auto& mb = model->bounds;
  const double w_m = model->voxel_size_m;
  EXPECT_LE(hi[1] - lo[1], (mb.max().z() - mb.min().z()) + 2 * w_m);
  EXPECT_GT(hi[1] - lo[1], 0.5 * (mb.max().z() - mb.min().z()));
  EXPECT_LT(lo[1], mb.max().z() + 2 * w_m);
  EXPECT_GT(hi[1], mb.min().z() - 2 * w_m);
  EXPECT_GT(-lo[2], mb.min().y() - 2 * w_m);
  EXPECT_LT(-hi[2], mb.max().y() + 2 * w_m);
}

TEST_F(Gltf, BadInputIsAClearErrorAndWritesNothing) {
  GltfExportJob job;
  job.model = *root_ / "model";
  job.out = *root_ / "x.gltf";
  auto r = export_gltf(job);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find(".glb"), std::string::npos);
  // A model without a mesh.
  fs::copy(*root_ / "model", *root_ / "no_mesh", fs::copy_options::recursive);
  auto m = load_model(*root_ / "no_mesh");
  ASSERT_TRUE(m);
  m->patch_mesh.reset();
  m->surface_mesh.reset();
  ASSERT_TRUE(save_model(*root_ / "no_mesh", *m));
  job.model = *root_ / "no_mesh";
  job.out = *root_ / "no_mesh.glb";
  r = export_gltf(job);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("no patch mesh"), std::string::npos) << r.error().message;
  EXPECT_FALSE(fs::exists(job.out));
  job.mesh = "surface";
  r = export_gltf(job);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("no fused surface"), std::string::npos) << r.error().message;
  job.mesh = "voxels";
  EXPECT_FALSE(export_gltf(job));
  job.mesh = "patch";
  job.model = *root_ / "missing";
  EXPECT_FALSE(export_gltf(job));
  EXPECT_FALSE(fs::exists(job.out));
}

}  // namespace
