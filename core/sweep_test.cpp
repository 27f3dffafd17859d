// Sweep tables and their plots: quotes in a title, a series' name or the
// folder reach gnuplot and the shell as text, never as syntax.
#include "core/sweep.h"

#include <gtest/gtest.h>

#include <fstream>

#include "core/image_io.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

TEST(Sweep, QuotesInTitlesSeriesAndPathsPlot) {
  const fs::path dir = fs::temp_directory_path() / ("s2r_sweep_it's " + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  SweepTable t;
  t.columns = {"seconds", "psnr_db"};
  t.rows = {{60, 26.2}, {300, 27.5}, {600, 30.5}};
  t.row_labels = {"lego's fit", "lego's fit", "lego's fit"};
  ASSERT_TRUE(t.write_csv(dir / "fit.csv"));
  PlotSpec spec{"lego val: fitted billboards' PSNR against the fit's seconds", "fit's seconds", "PSNR (dB)", "seconds",
                {"psnr_db"}, true, false, false};
  auto st = plot_png(t, spec, dir / "fit.png");
  ASSERT_TRUE(st) << st.error().message;
  auto png = read_image_u8(dir / "fit.png");
  ASSERT_TRUE(png) << png.error().message;
  EXPECT_EQ(png->width, 900);
  // No temporary left beside it.
  size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 2u);
  // A missing column is a clear error.
  spec.x = "minutes";
  st = plot_png(t, spec, dir / "other.png");
  ASSERT_FALSE(st);
  EXPECT_NE(st.error().message.find("minutes"), std::string::npos);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace s2r
