// Path safety (docs/formats.md): nothing written inside a session, a model or a
// Stanford .conf makes the program read or write outside its folder: no
// absolute names, no '..', no symbolic link that leads out, wherever it is.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "capture/session.h"
#include "capture/stanford_conf.h"
#include "core/atomic_file.h"
#include "core/json_fields.h"
#include "reconstruct/model.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

class PathSafety : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() / ("s2r_paths_" + std::to_string(::getpid()) + "_" +
                                         ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root_);
    fs::create_directories(root_ / "outside");
    std::ofstream(root_ / "outside" / "secret.png") << "not yours";
  }
  void TearDown() override { fs::remove_all(root_); }

  fs::path make_session() {
    const fs::path dir = root_ / "session";
    Session h;
    h.root = dir;
    h.name = "t";
    Intrinsics k;
    k.width = 8; k.height = 6; k.fx = 8; k.fy = 8; k.cx = 3.5; k.cy = 2.5;
    h.color = ColorSensor{"test", "mem", "RGB8", k, 1000, 1};
    auto w = SessionWriter::create(h);
    EXPECT_TRUE(w);
    for (int i = 0; i < 2; ++i) {
      ImageU8 c(8, 6, 3, 100);
      Frame f;
      f.index = i;
      EXPECT_TRUE(w->add_frame(f, &c, nullptr));
    }
    return dir;
  }

  fs::path make_model() {
    const fs::path dir = root_ / "model";
    fs::create_directories(dir);
    Model m;
    m.voxel_size_m = 0.01;
    m.bounds = Eigen::AlignedBox3d(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones());
    ModelCamera c;
    c.intrinsics.width = 8; c.intrinsics.height = 6; c.intrinsics.fx = 8; c.intrinsics.fy = 8;
    m.cameras.push_back(c);
    m.facets.push_back(FacetRecord{{0, 0, 0}, 0.01f, {0, 0, 1}, 1, 0, 1});
    m.facet_cameras = {0};
    EXPECT_TRUE(save_model(dir, m));
    std::ofstream(dir / "patches.ply") << "ply";
    return dir;
  }

  static std::string error_of(const Result<Session>& r) { return r ? "loaded" : r.error().message; }
  static std::string error_of(const Result<Model>& r) { return r ? "loaded" : r.error().message; }
  fs::path root_;
};

TEST_F(PathSafety, SessionLinksAnywhereThatLeaveAreRefused) {
  const fs::path s = make_session();
  ASSERT_TRUE(load_session(s));
  // A link inside the folder to inside the folder is fine.
  fs::create_symlink(s / "color" / "0000.png", s / "color" / "alias.png");
  ASSERT_TRUE(load_session(s));
  // A link that no file names still refuses the session: ground truth, a
  // subfolder, the journal are read by fixed names.
  fs::create_symlink(root_ / "outside", s / "ground_truth");
  auto e = error_of(load_session(s));
  EXPECT_NE(e.find("ground_truth' is a symbolic link to outside the folder"), std::string::npos) << e;
  fs::remove(s / "ground_truth");
  fs::rename(s / "session.journal", root_ / "journal");
  fs::create_symlink("../outside/secret.png", s / "session.journal");
  e = error_of(load_session(s));
  EXPECT_NE(e.find("session.journal"), std::string::npos) << e;
  fs::remove(s / "session.journal");
  fs::rename(root_ / "journal", s / "session.journal");
  ASSERT_TRUE(load_session(s));
}

TEST_F(PathSafety, ResumeThroughALinkTouchesNothingOutside) {
  const fs::path s = make_session();
  // A kill's leftover temporary, but in a folder the session reaches by a link.
  std::ofstream(root_ / "outside" / "0009.png.tmp-1") << "someone else's";
  fs::rename(s / "color", root_ / "color_moved");
  fs::create_symlink(root_ / "outside", s / "color");
  auto w = SessionWriter::resume(s);
  ASSERT_FALSE(w);
  EXPECT_NE(w.error().message.find("outside the folder"), std::string::npos) << w.error().message;
  EXPECT_TRUE(fs::exists(root_ / "outside" / "0009.png.tmp-1")) << "resume deleted a file outside the session";
  EXPECT_TRUE(fs::exists(root_ / "outside" / "secret.png"));
}

TEST_F(PathSafety, ModelNamesAndLinksStayInside) {
  const fs::path m = make_model();
  ASSERT_TRUE(load_model(m)) << error_of(load_model(m));
  auto doc = *parse_json_file(m / "model.json");
  for (const auto& [key, value, says] : {std::tuple{"patch_mesh", "../outside/secret.png", "escapes"},
                                         std::tuple{"surface_mesh", "/etc/hostname", "absolute"},
                                         std::tuple{"environment", "../../x.exr", "escapes"}}) {
    auto bad = doc;
    bad[key] = value;
    ASSERT_TRUE(write_file_atomic(m / "model.json", bad.dump()));
    const auto e = error_of(load_model(m));
    EXPECT_NE(e.find(key), std::string::npos) << e;
    EXPECT_NE(e.find(says), std::string::npos) << e;
  }
  auto bad = doc;
  bad["cameras"][0]["texture"] = "../outside/secret.png";
  ASSERT_TRUE(write_file_atomic(m / "model.json", bad.dump()));
  EXPECT_NE(error_of(load_model(m)).find("escapes"), std::string::npos);
  ASSERT_TRUE(write_file_atomic(m / "model.json", doc.dump()));
  fs::create_directories(m / "cameras");
  fs::create_symlink(root_ / "outside" / "secret.png", m / "cameras" / "0000.exr");
  EXPECT_NE(error_of(load_model(m)).find("symbolic link to outside"), std::string::npos);
}

TEST_F(PathSafety, StanfordConfScansStayBesideTheConf) {
  const fs::path dir = root_ / "scans";
  fs::create_directories(dir);
  const fs::path conf = dir / "scan.conf";
  for (const auto& [name, says] : {std::pair{"../outside/secret.png", "escapes"}, std::pair{"/etc/hostname", "absolute"},
                                   std::pair{"link.ply", "outside"}}) {
    std::ofstream(conf) << "camera 0 0 0 0 0 0 1\nbmesh " << name << " 0 0 0 0 0 0 1\n";
    if (std::string(name) == "link.ply") fs::create_symlink(root_ / "outside" / "secret.png", dir / "link.ply");
    auto c = read_stanford_conf(conf);
    ASSERT_FALSE(c) << name;
    EXPECT_NE(c.error().message.find(says), std::string::npos) << c.error().message;
  }
  std::ofstream(conf) << "bmesh inside.ply 0 0 0 0 0 0 1\n";
  EXPECT_TRUE(read_stanford_conf(conf));
}

}  // namespace
}  // namespace s2r
