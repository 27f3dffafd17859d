#include "capture/synth_rig.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <random>

#include "core/atomic_file.h"
#include "core/image_io.h"
#include "core/json_fields.h"
#include "core/progress.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

// The acceptance case of the rig, exactly `s2r synth --scene fuzzy --views 24 --seed 7`.
class FuzzySession : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() / ("s2r_fuzzy_" + std::to_string(::getpid())));
    fs::remove_all(*dir_);
    SynthOptions o;
    set_progress_enabled(false);
    o.scene = "fuzzy";
    o.views = 24;
    o.seed = 7;
    auto r = synth_session(o, *dir_);
    ASSERT_TRUE(r) << r.error().message;
    report_ = new Report(*r);
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
    delete report_;
  }
  static fs::path* dir_;
  static Report* report_;
};
fs::path* FuzzySession::dir_ = nullptr;
Report* FuzzySession::report_ = nullptr;

TEST_F(FuzzySession, LoadsBackWithEveryFrame) {
  auto s = load_session(*dir_);
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_EQ(s->frames.size(), 24u);
  EXPECT_EQ(s->source, "synth:fuzzy");
  ASSERT_TRUE(s->depth);
  auto c = load_color(*s, s->frames[5]);
  ASSERT_TRUE(c);
  EXPECT_EQ(c->channels, 3);
}

// Exact depth of view i, unprojected and reprojected into view j, lands
// where view j's exact depth says the same surface point is.
TEST_F(FuzzySession, GroundTruthDepthReprojectsBetweenViews) {
  auto truth = load_ground_truth(*dir_);
  ASSERT_TRUE(truth) << truth.error().message;
  const Intrinsics& Kc = truth->color;
  double worst = 0, sum = 0;
  int n = 0;
  for (int i = 0; i < 24; i += 3) {
    const int j = (i + 1) % 24;  // neighbouring view, 15 degrees apart
    auto di = *read_image_float(*dir_ / "ground_truth" / "depth_color" / frame_file_name(i, "exr"));
    auto dj = *read_image_float(*dir_ / "ground_truth" / "depth_color" / frame_file_name(j, "exr"));
    const auto& wi = truth->world_from_camera[size_t(i)];
    const auto& wj = truth->world_from_camera[size_t(j)];
    const Eigen::Isometry3d j_from_i = wj.inverse() * wi;
    for (int y = 2; y < Kc.height - 2; y += 4)
      for (int x = 2; x < Kc.width - 2; x += 4) {
        const float z = di.at(x, y);
        if (z <= 0) continue;
        const Eigen::Vector3d pj = j_from_i * *Kc.unproject({double(x), double(y)}, z);
        auto q = Kc.project(pj);
        if (!q || !Kc.contains(*q)) continue;
        // Compare against view j's own surface: only where it sees the same point.
        const int u = int(std::lround(q->x())), v = int(std::lround(q->y()));
        if (u < 1 || v < 1 || u >= Kc.width - 1 || v >= Kc.height - 1) continue;
        const float zj = dj.at(u, v);
        if (zj <= 0 || std::abs(zj - pj.z()) > 0.002) continue;  // occluded or a strand edge
        // Back from view j's exact depth at the projected pixel (bilinear) to view i.
        auto lerp = [&](double px, double py) {
          const int x0 = int(std::floor(px)), y0 = int(std::floor(py));
          const double a = px - x0, b = py - y0;
          const float z00 = dj.at(x0, y0), z10 = dj.at(x0 + 1, y0), z01 = dj.at(x0, y0 + 1), z11 = dj.at(x0 + 1, y0 + 1);
          if (z00 <= 0 || z10 <= 0 || z01 <= 0 || z11 <= 0) return -1.0;
          const double zs[] = {z00, z10, z01, z11};
          const double lo = *std::min_element(zs, zs + 4), hi = *std::max_element(zs, zs + 4);
          if (hi - lo > 0.002) return -1.0;  // discontinuity: not a surface sample
          // Bilinear interpolation is exact only on a planar patch: skip creases.
          if (std::abs(z00 + z11 - z10 - z01) > 1e-5) return -1.0;
          return (1 - a) * (1 - b) * z00 + a * (1 - b) * z10 + (1 - a) * b * z01 + a * b * z11;
        };
        const double zb = lerp(q->x(), q->y());
        if (zb <= 0) continue;
        const Eigen::Vector3d back = j_from_i.inverse() * *Kc.unproject(*q, zb);
        auto r = Kc.project(back);
        ASSERT_TRUE(r);
        const double e = (*r - Eigen::Vector2d(x, y)).norm();
        worst = std::max(worst, e);
        sum += e;
        ++n;
      }
  }
  ASSERT_GT(n, 500);
  RecordProperty("reprojection_mean_px", std::to_string(sum / n));
  RecordProperty("reprojection_max_px", std::to_string(worst));
  EXPECT_LT(sum / n, 0.01);
  // Bilinear interpolation across curved surfaces bounds the worst case.
  EXPECT_LT(worst, 0.05) << "mean " << sum / n << " over " << n;
}

TEST_F(FuzzySession, DepthShowsTheSensorModel) {
  // Holes on the strands, valid depth on the core, noise near the model's sigma.
  size_t strand = 0, strand_hole = 0, surface = 0, surface_valid = 0;
  for (int i = 0; i < 24; i += 6) {
    auto labels = *read_image_u8(*dir_ / "ground_truth" / "labels" / frame_file_name(i, "png"));
    auto depth = *read_image_u16(*dir_ / "depth" / frame_file_name(i, "png"));
    for (size_t p = 0; p < depth.pixels(); ++p) {
      if (labels.data[p] == 2) {
        ++strand;
        strand_hole += depth.data[p] == 0;
      } else if (labels.data[p] == 1) {
        ++surface;
        surface_valid += depth.data[p] != 0;
      }
    }
  }
  ASSERT_GT(strand, 1000u);
  EXPECT_GT(double(strand_hole) / strand, 0.6) << "strands must mostly be holes";
  EXPECT_GT(double(surface_valid) / surface, 0.6) << "solid surfaces mostly measured";
  EXPECT_GT(report_->errors.at("depth_rms_mm"), 0.2);
  EXPECT_LT(report_->errors.at("depth_rms_mm"), 2.0);
}

// Walks truncations and corrupted byte ranges of the rig's real session.json,
// and truncations of its images: each load ends in a session or a clear error.
TEST_F(FuzzySession, CorruptedFilesGiveClearErrorsNeverACrash) {
  const fs::path copy = dir_->string() + "_walk";
  fs::remove_all(copy);
  fs::copy(*dir_, copy, fs::copy_options::recursive);
  fs::remove(copy / "session.journal");  // the journal alone would restore every frame
  const auto text = *read_file(copy / "session.json");
  ASSERT_GT(text.size(), 4000u);
  size_t rejected = 0, loads = 0;
  for (size_t n = 0; n < text.size(); n += 1 + n / 400) {
    ASSERT_TRUE(write_file_atomic(copy / "session.json", text.substr(0, n)));
    auto s = load_session(copy, {.check_images = false});
    ++loads;
    if (!s) {
      ++rejected;
      ASSERT_NE(s.error().message.find("session.json"), std::string::npos) << s.error().message;
    }
  }
  EXPECT_EQ(rejected, loads);  // no proper prefix of the document is a document
  std::mt19937 rng(3);
  for (int trial = 0; trial < 1500; ++trial) {
    std::string bad = text;
    const size_t at = rng() % bad.size(), len = 1 + rng() % 32;
    for (size_t k = at; k < std::min(bad.size(), at + len); ++k) bad[k] = static_cast<char>(rng() % 256);
    ASSERT_TRUE(write_file_atomic(copy / "session.json", bad));
    auto s = load_session(copy, {.check_images = trial % 10 == 0});
    if (!s) {
      EXPECT_FALSE(s.error().message.empty());
    }
  }
  ASSERT_TRUE(write_file_atomic(copy / "session.json", text));
  auto s = load_session(copy);
  ASSERT_TRUE(s) << s.error().message;
  for (const char* kind : {"color", "depth"}) {
    const fs::path img = copy / kind / "0011.png";
    const auto bytes = *read_file(img);
    for (size_t keep : {size_t(0), size_t(7), size_t(33), bytes.size() / 3, bytes.size() - 30}) {
      ASSERT_TRUE(write_file_atomic(img, bytes.substr(0, keep)));
      const bool color = std::string(kind) == "color";
      std::string message;
      if (color) {
        auto r = load_color(*s, s->frames[11]);
        ASSERT_FALSE(r) << kind << " kept " << keep;
        message = r.error().message;
      } else {
        auto r = load_depth(*s, s->frames[11]);
        ASSERT_FALSE(r) << kind << " kept " << keep;
        message = r.error().message;
      }
      EXPECT_NE(message.find("0011.png"), std::string::npos) << message;
      if (keep > 33) continue;  // the session loader reads headers only; decoding is load_color/--decode
      auto loaded = load_session(copy);
      ASSERT_FALSE(loaded) << kind << " kept " << keep;
      EXPECT_NE(loaded.error().message.find(std::string("frames[11].") + kind), std::string::npos)
          << loaded.error().message;
    }
    ASSERT_TRUE(write_file_atomic(img, bytes));
  }
  fs::remove_all(copy);
}

TEST(SynthRig, DeterministicForASeedWhateverTheThreads) {
  SynthOptions o;
  o.scene = "blob";
  o.views = 4;
  o.width = 96;
  o.height = 72;
  o.threads = 1;
  auto a = SynthRig::create(o);
  ASSERT_TRUE(a) << a.error().message;
  o.threads = 2;
  auto b = SynthRig::create(o);
  ASSERT_TRUE(b);
  o.seed = 8;
  auto c = SynthRig::create(o);
  ASSERT_TRUE(c);
  const auto va = (*a)->render(1), vb = (*b)->render(1), vc = (*c)->render(1);
  EXPECT_EQ(va.color.data, vb.color.data);
  EXPECT_EQ(va.depth.data, vb.depth.data);
  EXPECT_NE(va.color.data, vc.color.data);
}

TEST(SynthRig, RoomIsCameraCentred) {
  SynthOptions o;
  o.scene = "room";
  o.views = 8;
  o.width = 64;
  o.height = 48;
  auto rig = SynthRig::create(o);
  ASSERT_TRUE(rig) << rig.error().message;
  EXPECT_EQ((*rig)->layout(), Layout::kCameraCentre);
  // Every pixel sees a wall: the camera is inside the room.
  auto v = (*rig)->render(3);
  for (float z : v.gt_depth.data) EXPECT_GT(z, 0.2f);
}

TEST(SynthRig, RejectsBadOptions) {
  SynthOptions o;
  o.views = 0;
  EXPECT_FALSE(SynthRig::create(o));
  o.views = 4;
  o.scene = "teapot";
  auto r = SynthRig::create(o);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("unknown scene"), std::string::npos);
}

}  // namespace
}  // namespace s2r
