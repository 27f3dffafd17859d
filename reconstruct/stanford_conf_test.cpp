// The Stanford .conf convention, established by measuring alignment: ring
// scans placed by each candidate reading of the quaternion are compared
// where they overlap. Also: the file is written back in its own format.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "capture/stanford_conf.h"
#include "core/mesh.h"
#include "reconstruct/view_cloud.h"

namespace fs = std::filesystem;
using namespace s2r;

namespace {

const fs::path kBunny = fs::path(S2R_DATA_DIR) / "stanford_bunny";

// Median distance from a's points (placed by ta) to b's (placed by tb), over
// the points that have a neighbour within `reach`; and the fraction that do.
std::pair<double, double> agreement(const ViewCloud& a, const Eigen::Isometry3d& ta, const ViewCloud& b,
                                    const Eigen::Isometry3d& tb, float reach) {
  std::vector<Eigen::Vector3f> bw;
  for (const auto& p : b.points) bw.push_back((tb * p.cast<double>()).cast<float>());
  NeighbourIndex index(bw);
  std::vector<double> d;
  for (const auto& p : a.points) {
    float d2 = 0;
    if (index.nearest((ta * p.cast<double>()).cast<float>(), reach, &d2) >= 0) d.push_back(std::sqrt(d2));
  }
  if (d.empty()) return {1e9, 0};
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return {d[d.size() / 2], double(d.size()) / a.size()};
}

ViewCloud load(const std::string& file) {
  auto scan = read_ply_points(kBunny / file);
  EXPECT_TRUE(scan) << scan.error().message;
  EXPECT_GT(scan->grid_width, 0) << "range grid not read";
  auto v = prepare_view(*scan, {});
  EXPECT_TRUE(v);
  return downsample(*v, 0.001);
}

}  // namespace

TEST(StanfordConf, ReadingThatAlignsTheRingScans) {
  if (!fs::exists(kBunny / "bun.conf")) GTEST_SKIP() << "real data not found at " << kBunny;
  auto conf = read_stanford_conf(kBunny / "bun.conf");
  ASSERT_TRUE(conf) << conf.error().message;
  ASSERT_EQ(conf->scans.size(), 10u);
  std::map<std::string, Eigen::Isometry3d> pose;
  for (const auto& s : conf->scans) pose[s.file] = s.world_from_scan;
  const std::vector<std::pair<std::string, std::string>> pairs = {
      {"bun000.ply", "bun045.ply"}, {"bun045.ply", "bun090.ply"}, {"bun270.ply", "bun315.ply"},
      {"bun315.ply", "bun000.ply"}};
  for (const auto& [fa, fb] : pairs) {
    const ViewCloud a = load(fa), b = load(fb);
    auto as_read = [&](const std::string& f) { return pose.at(f); };
    auto usual = [&](const std::string& f) {  // R(q) of (qx, qy, qz, qw) read the usual way
      Eigen::Isometry3d t = pose.at(f);
      t.linear() = t.linear().transpose().eval();
      return t;
    };
    auto inverse = [&](const std::string& f) { return pose.at(f).inverse(); };
    const auto [d_read, o_read] = agreement(a, as_read(fa), b, as_read(fb), 0.005f);
    const auto [d_usual, o_usual] = agreement(a, usual(fa), b, usual(fb), 0.005f);
    const auto [d_inv, o_inv] = agreement(a, inverse(fa), b, inverse(fb), 0.005f);
    SCOPED_TRACE(fa + " vs " + fb);
    auto gap = [](double d) { return d < 1 ? 1e3 * d : -1.0; };  // -1: no overlap within 5 mm
    std::printf("%s vs %s: median gap mm / overlap: file's reading %.2f / %.0f %%, usual reading %.2f / %.0f %%, "
                "inverse %.2f / %.0f %%\n", fa.c_str(), fb.c_str(), gap(d_read), 100 * o_read, gap(d_usual),
                100 * o_usual, gap(d_inv), 100 * o_inv);
    // Registered scans agree to the scanner's noise where they overlap.
    EXPECT_LT(d_read, 0.0006) << "overlap " << o_read;
    EXPECT_GT(o_read, 0.25);
    // The other readings leave the scans visibly apart (or barely overlapping).
    EXPECT_TRUE(d_usual > 3 * d_read || o_usual < 0.5 * o_read) << d_usual << " " << o_usual;
    EXPECT_TRUE(d_inv > 3 * d_read || o_inv < 0.5 * o_read) << d_inv << " " << o_inv;
  }
  // bun045 is turned by about 34 deg, not 45.
  const double a045 = Eigen::AngleAxisd(pose.at("bun045.ply").linear()).angle() * 180 / M_PI;
  EXPECT_NEAR(a045, 34.3, 0.5);
}

TEST(StanfordConf, WrittenBackUnchangedPosesGiveTheSameNumbers) {
  if (!fs::exists(kBunny / "bun.conf")) GTEST_SKIP() << "real data not found at " << kBunny;
  auto conf = read_stanford_conf(kBunny / "bun.conf");
  ASSERT_TRUE(conf);
  const fs::path out = fs::path(testing::TempDir()) / "roundtrip.conf";
  ASSERT_TRUE(write_stanford_conf(out, *conf));
  auto again = read_stanford_conf(out);
  ASSERT_TRUE(again);
  ASSERT_EQ(again->scans.size(), conf->scans.size());
  for (size_t i = 0; i < conf->scans.size(); ++i) {
    EXPECT_EQ(again->scans[i].file, conf->scans[i].file);
    // Same quaternion sign as the input (qw < 0 stays < 0 for top3 and ear_back).
    EXPECT_GT(again->scans[i].as_read.coeffs().dot(conf->scans[i].as_read.coeffs()), 0.999999);
    EXPECT_LT((again->scans[i].world_from_scan.matrix() - conf->scans[i].world_from_scan.matrix())
                  .cwiseAbs().maxCoeff(), 1e-7);
  }
  std::ifstream in(out);
  std::string first;
  std::getline(in, first);
  EXPECT_EQ(first.rfind("camera ", 0), 0u) << "non-bmesh lines are kept";
}

TEST(StanfordConf, BadFilesAreClearErrors) {
  const fs::path dir = fs::path(testing::TempDir()) / "badconf";
  fs::create_directories(dir);
  auto write = [&](const std::string& text) {
    std::ofstream(dir / "x.conf") << text;
    return read_stanford_conf(dir / "x.conf");
  };
  auto r = write("bmesh a.ply 0 0 0 0 0 0\n");
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("line 1"), std::string::npos);
  EXPECT_FALSE(write("bmesh a.ply 0 0 0 0 0 0 2\n"));          // not unit
  EXPECT_FALSE(write("bmesh a.ply nan 0 0 0 0 0 1\n"));        // not finite
  EXPECT_FALSE(write("bmesh ../a.ply 0 0 0 0 0 0 1\n"));       // escapes the folder
  EXPECT_FALSE(write("camera 0 0 0 0 0 0 1\n"));               // no scans
  EXPECT_FALSE(read_stanford_conf(dir / "missing.conf"));
}
