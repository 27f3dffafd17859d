// Exports (reconstruct/session_export.h) read back by their own tools: COLMAP
// 3.8 (Debian's `colmap`: model_converter to binary, model_analyzer) and this
// project's importers (a round trip of cameras and poses); bad input leaves
// nothing written.
#include "reconstruct/session_export.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "capture/colmap_model.h"
#include "capture/ground_truth.h"
#include "capture/import_datasets.h"
#include "capture/session.h"
#include "capture/synth_rig.h"
#include "core/progress.h"
#include "core/shell.h"

namespace {
namespace fs = std::filesystem;
using namespace s2r;

std::string run(const std::string& cmd, int* code) {
  const ShellRun r = run_shell(cmd + " 2>&1");
  *code = r.code;
  return r.output;
}

class Export : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    set_progress_enabled(false);
    root_ = new fs::path(fs::temp_directory_path() / ("s2r_export_" + std::to_string(::getpid())));
    fs::remove_all(*root_);
    SynthOptions o;
    o.scene = "blob";
    o.views = 6;
    o.width = 128;
    o.height = 96;
    ASSERT_TRUE(synth_session(o, *root_ / "session"));
  }
  static void TearDownTestSuite() {
    fs::remove_all(*root_);
    delete root_;
  }
  static fs::path* root_;

  // The session's frames against another session's: same intrinsics, same poses.
  static void expect_same_cameras(const fs::path& a_dir, const fs::path& b_dir, double pose_tol) {
    auto a = load_session(a_dir);
    auto b = load_session(b_dir);
    ASSERT_TRUE(a) << a.error().message;
    ASSERT_TRUE(b) << b.error().message;
    ASSERT_EQ(a->frames.size(), b->frames.size());
    auto truth = ground_truth_poses(a_dir, a->frames.size());
    ASSERT_TRUE(truth);
    // Matched by name: an exported frame is frame_NNNN (its index); a reader
    // may list them in another order (COLMAP's binary model does).
    std::map<int, const Frame*> by_index;
    for (const auto& f : b->frames) {
      const auto at = f.source.find("frame_");
      ASSERT_NE(at, std::string::npos) << f.source;
      by_index[std::stoi(f.source.substr(at + 6, 4))] = &f;
    }
    for (size_t i = 0; i < a->frames.size(); ++i) {
      ASSERT_TRUE(by_index.count(a->frames[i].index)) << i;
      const Frame& fb = *by_index[a->frames[i].index];
      const auto ka = a->color_intrinsics(a->frames[i]);
      const auto kb = b->color_intrinsics(fb);
      ASSERT_TRUE(ka && kb);
      EXPECT_NEAR(ka->fx, kb->fx, 1e-6);
      EXPECT_NEAR(ka->fy, kb->fy, 1e-6);
      EXPECT_NEAR(ka->cx, kb->cx, 1e-6);
      EXPECT_NEAR(ka->cy, kb->cy, 1e-6);
      for (int k = 0; k < 5; ++k) EXPECT_NEAR(ka->dist[k], kb->dist[k], 1e-9);
      ASSERT_TRUE(fb.world_from_camera);
      EXPECT_LT(((*truth)[i].matrix() - fb.world_from_camera->matrix()).cwiseAbs().maxCoeff(), pose_tol) << i;
    }
  }
};
fs::path* Export::root_ = nullptr;

TEST_F(Export, ColmapModelIsReadByColmapAndImportsBackToTheSameCameras) {
  ExportJob job;
  job.format = "colmap";
  job.session = *root_ / "session";
  job.out = *root_ / "colmap";
  auto r = export_session(job);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->counts.at("frames"), 6);
  const int points = static_cast<int>(r->counts.at("points"));
  EXPECT_GT(points, 500);  // the rig's depth fused
  EXPECT_GE(r->counts.at("observations"), 2.0 * points);  // a turntable ring: most points seen twice or more
  for (const char* f : {"cameras.txt", "images.txt", "points3D.txt", "report.json", "images/frame_0000.png"})
    EXPECT_TRUE(fs::exists(*root_ / "colmap" / f)) << f;

  int code = 0;
  if (run("command -v colmap", &code).empty() || code != 0) GTEST_SKIP() << "colmap not installed (scripts/setup installs it)";
  fs::create_directories(*root_ / "colmap_bin");
  const std::string out = run("QT_QPA_PLATFORM=offscreen colmap model_converter --input_path " + (*root_ / "colmap").string() +
                                  " --output_path " + (*root_ / "colmap_bin").string() + " --output_type BIN",
                              &code);
  ASSERT_EQ(code, 0) << out;
  const std::string analysed =
      run("QT_QPA_PLATFORM=offscreen colmap model_analyzer --path " + (*root_ / "colmap_bin").string(), &code);
  ASSERT_EQ(code, 0) << analysed;
  EXPECT_NE(analysed.find("Images: 6"), std::string::npos) << analysed;
  EXPECT_NE(analysed.find("Points: " + std::to_string(points)), std::string::npos) << analysed;
  // COLMAP's own binary, read back: the same cameras and poses as the session's truth.
  auto model = read_colmap_model(*root_ / "colmap_bin");
  ASSERT_TRUE(model) << model.error().message;
  EXPECT_EQ(model->encoding, "binary");
  EXPECT_EQ(model->points3d, static_cast<size_t>(points));
  // And back to text by COLMAP: the same cameras and poses again.
  fs::create_directories(*root_ / "colmap_txt");
  const std::string back = run("QT_QPA_PLATFORM=offscreen colmap model_converter --input_path " + (*root_ / "colmap_bin").string() +
                                   " --output_path " + (*root_ / "colmap_txt").string() + " --output_type TXT",
                               &code);
  ASSERT_EQ(code, 0) << back;
  auto text = read_colmap_model(*root_ / "colmap_txt");
  ASSERT_TRUE(text) << text.error().message;
  EXPECT_EQ(text->encoding, "text");
  ASSERT_EQ(text->images.size(), model->images.size());
  EXPECT_EQ(text->points3d, model->points3d);
  std::map<std::string, const ColmapImage*> by_name;
  for (const auto& im : model->images) by_name[im.name] = &im;
  for (const auto& im : text->images) {
    ASSERT_TRUE(by_name.count(im.name)) << im.name;
    EXPECT_LT((im.cam_from_world.matrix() - by_name[im.name]->cam_from_world.matrix()).cwiseAbs().maxCoeff(), 1e-9) << im.name;
    const auto& a = text->cameras.at(im.camera).K;
    const auto& b = model->cameras.at(by_name[im.name]->camera).K;
    EXPECT_EQ(text->cameras.at(im.camera).model, model->cameras.at(by_name[im.name]->camera).model);
    EXPECT_NEAR(a.fx, b.fx, 1e-9);
    EXPECT_NEAR(a.cx, b.cx, 1e-9);
  }
  ImportOptions io;
  io.images = *root_ / "colmap" / "images";
  auto imp = import_dataset("colmap", *root_ / "colmap_bin", *root_ / "back_colmap", io);
  ASSERT_TRUE(imp) << imp.error().message;
  expect_same_cameras(*root_ / "session", *root_ / "back_colmap", 1e-9);
}

TEST_F(Export, NerfstudioTransformsImportBackToTheSameCameras) {
  ExportJob job;
  job.format = "nerfstudio";
  job.session = *root_ / "session";
  job.out = *root_ / "ns";
  auto r = export_session(job);
  ASSERT_TRUE(r) << r.error().message;
  auto imp = import_dataset("nerf", *root_ / "ns", *root_ / "back_ns", {});
  ASSERT_TRUE(imp) << imp.error().message;
  expect_same_cameras(*root_ / "session", *root_ / "back_ns", 1e-9);
}

TEST_F(Export, BadInputIsAClearErrorAndWritesNothing) {
  // A non-empty folder is left as it was.
  fs::create_directories(*root_ / "full");
  std::ofstream(*root_ / "full" / "keep.txt") << "mine";
  ExportJob job;
  job.format = "colmap";
  job.session = *root_ / "session";
  job.out = *root_ / "full";
  auto r = export_session(job);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("not empty"), std::string::npos) << r.error().message;
  EXPECT_EQ(std::distance(fs::directory_iterator(*root_ / "full"), fs::directory_iterator()), 1);
  // A session without poses: no folder, no temporary left behind.
  fs::copy(*root_ / "session", *root_ / "no_poses", fs::copy_options::recursive);
  fs::remove_all(*root_ / "no_poses" / "ground_truth");
  job.session = *root_ / "no_poses";
  job.out = *root_ / "np_out";
  r = export_session(job);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("poses"), std::string::npos) << r.error().message;
  EXPECT_FALSE(fs::exists(*root_ / "np_out"));
  for (const auto& e : fs::directory_iterator(*root_))
    EXPECT_EQ(e.path().filename().string().find(".partial"), std::string::npos) << e.path();
  job.format = "ply";
  job.session = *root_ / "session";
  EXPECT_FALSE(export_session(job));
}

}  // namespace
