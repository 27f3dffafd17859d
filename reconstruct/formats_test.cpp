#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>

#include "core/atomic_file.h"
#include "core/json_fields.h"
#include "reconstruct/model.h"
#include "reconstruct/poses.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

fs::path temp(const std::string& name) {
  auto p = fs::temp_directory_path() / ("s2r_fmt_" + std::to_string(::getpid()) + "_" + name);
  fs::remove_all(p);
  return p;
}

TEST(PosesFile, RoundTripAndValidation) {
  const fs::path path = temp("poses.json");
  Poses p;
  p.session = "s";
  p.rms_m = 0.0007;
  for (int i = 0; i < 3; ++i) {
    FramePose f;
    f.index = i;
    f.world_from_camera = Eigen::Isometry3d(Eigen::AngleAxisd(0.3 * i, Eigen::Vector3d::UnitZ()));
    f.residual_rms_m = 0.001 * i;
    p.frames.push_back(f);
  }
  p.frames[2].flagged = true;
  ASSERT_TRUE(save_poses(path, p));
  auto q = load_poses(path);
  ASSERT_TRUE(q) << q.error().message;
  ASSERT_EQ(q->frames.size(), 3u);
  EXPECT_TRUE(q->frames[2].flagged);
  EXPECT_TRUE(q->frames[1].world_from_camera.isApprox(p.frames[1].world_from_camera, 1e-12));

  auto j = *parse_json_file(path);
  j["frames"][1]["index"] = 5;
  ASSERT_TRUE(write_file_atomic(path, j.dump()));
  auto e = load_poses(path);
  ASSERT_FALSE(e);
  EXPECT_NE(e.error().message.find("frames[1].index"), std::string::npos) << e.error().message;
  j["frames"][1]["index"] = 1;
  j["version"] = 2;
  ASSERT_TRUE(write_file_atomic(path, j.dump()));
  e = load_poses(path);
  ASSERT_FALSE(e);
  EXPECT_NE(e.error().message.find("version"), std::string::npos);
  fs::remove(path);
}

// A number beyond double's range made nlohmann::json throw out_of_range, which
// escaped every loader (found by fuzz/fuzz_poses.cpp).
TEST(PosesFile, NumberOverflowIsAClearError) {
  const fs::path path = temp("overflow.json");
  ASSERT_TRUE(write_file_atomic(path, R"({"format": "s2r.poses", "version": 1, "rms_m": -3.5e705})"));
  auto e = load_poses(path);
  ASSERT_FALSE(e);
  EXPECT_NE(e.error().message.find("not valid JSON"), std::string::npos) << e.error().message;
  fs::remove(path);
}

class ModelFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = temp("model");
    fs::create_directories(dir_);
    Model m;
    m.voxel_size_m = 0.004;
    m.bounds = Eigen::AlignedBox3d(Eigen::Vector3d(-0.1, -0.1, 0), Eigen::Vector3d(0.1, 0.1, 0.2));
    ModelCamera c;
    c.intrinsics.width = 64; c.intrinsics.height = 48; c.intrinsics.fx = c.intrinsics.fy = 50;
    c.intrinsics.cx = 31.5; c.intrinsics.cy = 23.5;
    m.cameras = {c, c};
    for (int i = 0; i < 100; ++i)
      m.facets.push_back({{0.001f * i, 0, 0.1f}, 0.004f, {0, 0, 1}, 0.5f, uint32_t(i % 2), 1});
    m.facet_cameras = {0, 1};
    ASSERT_TRUE(save_model(dir_, m));
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(ModelFiles, RoundTrip) {
  auto m = load_model(dir_);
  ASSERT_TRUE(m) << m.error().message;
  EXPECT_EQ(m->facets.size(), 100u);
  EXPECT_FLOAT_EQ(m->facets[7].center[0], 0.007f);
  EXPECT_EQ(m->cameras.size(), 2u);
}

TEST_F(ModelFiles, EveryTruncationOfThePayloadIsRejected) {
  const auto bytes = *read_file(dir_ / "facets.bin");
  for (size_t n = 0; n < bytes.size(); n += 7) {
    ASSERT_TRUE(write_file_atomic(dir_ / "facets.bin", bytes.substr(0, n)));
    auto m = load_model(dir_);
    ASSERT_FALSE(m) << n;
    EXPECT_NE(m.error().message.find("facets.bin"), std::string::npos) << m.error().message;
  }
}

TEST_F(ModelFiles, InconsistenciesAreRejected) {
  auto bytes = *read_file(dir_ / "facets.bin");
  bytes[100] ^= 0x40;  // a flipped bit
  ASSERT_TRUE(write_file_atomic(dir_ / "facets.bin", bytes));
  auto m = load_model(dir_);
  ASSERT_FALSE(m);
  EXPECT_NE(m.error().message.find("checksum"), std::string::npos);

  SetUp();
  auto j = *parse_json_file(dir_ / "model.json");
  j["payloads"]["facets"]["records"] = 99;
  ASSERT_TRUE(write_file_atomic(dir_ / "model.json", j.dump()));
  m = load_model(dir_);
  ASSERT_FALSE(m);
  EXPECT_NE(m.error().message.find("model.json says 99"), std::string::npos) << m.error().message;

  SetUp();
  j = *parse_json_file(dir_ / "model.json");
  j["cameras"].erase(1);  // facet_cameras still names camera 1
  ASSERT_TRUE(write_file_atomic(dir_ / "model.json", j.dump()));
  m = load_model(dir_);
  ASSERT_FALSE(m);
  EXPECT_NE(m.error().message.find("names camera 1 of 1"), std::string::npos) << m.error().message;

  SetUp();
  j = *parse_json_file(dir_ / "model.json");
  j["cameras"][0]["texture"] = "../../etc/passwd";
  ASSERT_TRUE(write_file_atomic(dir_ / "model.json", j.dump()));
  m = load_model(dir_);
  ASSERT_FALSE(m);
  EXPECT_NE(m.error().message.find("cameras[0].texture"), std::string::npos) << m.error().message;
}

TEST_F(ModelFiles, OctreeRoundTripAndBrokenLinks) {
  auto m = load_model(dir_);
  ASSERT_TRUE(m);
  EXPECT_TRUE(m->octree.empty());
  // A root with two leaf children.
  OctreeRecord root{{0, 0, 0.1f}, {0, 0, 1}, 0.2f, 0.001f, {0, 0, 0}, 1, 0, 2, 0};
  OctreeRecord leaf{{0, 0, 0.1f}, {0, 0, 1}, 0.1f, 0.f, {0, 0, 0}, kNoChild, 0x10, 0, 1};
  m->octree = {root, leaf, leaf};
  m->octree_max_level = 1;
  ASSERT_TRUE(save_model(dir_, *m));
  auto back = load_model(dir_);
  ASSERT_TRUE(back) << back.error().message;
  ASSERT_EQ(back->octree.size(), 3u);
  EXPECT_EQ(back->octree[0].first_child, 1u);
  EXPECT_EQ(back->octree[2].edge_flags, 0x10);
  // A child range past the end, a child on the wrong level, a cone beyond pi.
  for (int bad = 0; bad < 3; ++bad) {
    Model broken = *back;
    if (bad == 0) broken.octree[0].children = 3;
    if (bad == 1) broken.octree[1].level = 0;
    if (bad == 2) broken.octree[1].cone = 4.f;
    ASSERT_TRUE(save_model(dir_, broken));
    auto r = load_model(dir_);
    ASSERT_FALSE(r) << bad;
    EXPECT_NE(r.error().message.find("octree.bin: node"), std::string::npos) << r.error().message;
    // Opened without the octree, the model loads; the octree read later
    // meets the same check.
    auto deferred = load_model(dir_, ModelLoad{.octree = false});
    ASSERT_TRUE(deferred) << deferred.error().message;
    auto later = load_octree(dir_, *deferred);
    ASSERT_FALSE(later) << bad;
    EXPECT_NE(later.error().message.find("octree.bin: node"), std::string::npos) << later.error().message;
  }
  ASSERT_TRUE(save_model(dir_, *back));
  auto deferred = load_model(dir_, ModelLoad{.octree = false});
  ASSERT_TRUE(deferred) << deferred.error().message;
  EXPECT_TRUE(deferred->octree.empty());
  EXPECT_EQ(deferred->facets.size(), 100u);
  ASSERT_TRUE(load_octree(dir_, *deferred));
  ASSERT_EQ(deferred->octree.size(), 3u);
  EXPECT_EQ(deferred->octree_max_level, 1);
  EXPECT_EQ(deferred->octree[2].edge_flags, 0x10);
  // A model without an octree: nothing to read, no error.
  Model flat = *back;
  flat.octree.clear();
  ASSERT_TRUE(save_model(dir_, flat));
  auto none = load_model(dir_, ModelLoad{.octree = false});
  ASSERT_TRUE(none);
  EXPECT_TRUE(load_octree(dir_, *none));
  EXPECT_TRUE(none->octree.empty());
}

// The fitted billboards' pixel filter travels with the model; a model
// written before it (no key) draws without one, as it was fitted.
TEST_F(ModelFiles, SplatPixelFilterIsKeptAndOldModelsHaveNone) {
  auto m = load_model(dir_);
  ASSERT_TRUE(m);
  m->splat_layout = SplatLayout{0, 0.3f};
  m->splats = {0, 0, 0.1f, 0.002f, 0.5f, 0.1f, 0.2f, 0.3f};  // centre, sigma, opacity, SH degree 0
  ASSERT_TRUE(save_model(dir_, *m));
  auto back = load_model(dir_);
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_FLOAT_EQ(back->splat_layout.pixel_filter_px2, 0.3f);
  auto j = *parse_json_file(dir_ / "model.json");
  j.erase("splat_pixel_filter_px2");
  ASSERT_TRUE(write_file_atomic(dir_ / "model.json", j.dump()));
  back = load_model(dir_);
  ASSERT_TRUE(back) << back.error().message;
  EXPECT_FLOAT_EQ(back->splat_layout.pixel_filter_px2, 0.f);
  j["splat_pixel_filter_px2"] = 9;
  ASSERT_TRUE(write_file_atomic(dir_ / "model.json", j.dump()));
  back = load_model(dir_);
  ASSERT_FALSE(back);
  EXPECT_NE(back.error().message.find("splat_pixel_filter_px2"), std::string::npos) << back.error().message;
}

TEST(ReadFile, WholeFilesOfAnySize) {
  const fs::path path = temp("read_file");
  for (size_t n : {size_t(0), size_t(1), size_t(4096), size_t(1) << 20}) {
    std::string bytes(n, '\0');
    for (size_t i = 0; i < n; ++i) bytes[i] = char(i * 31 + 7);
    ASSERT_TRUE(write_file_atomic(path, bytes));
    auto back = read_file(path);
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(*back, bytes) << n;
  }
  fs::remove(path);
  auto gone = read_file(path);
  ASSERT_FALSE(gone);
  EXPECT_EQ(gone.error().code, ErrorCode::not_found);
}


}  // namespace
}  // namespace s2r
