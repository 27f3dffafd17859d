// Error-vs-time sweeps (`s2r bench`): a table of measurements written as CSV
// and drawn as a PNG plot with gnuplot (Debian's gnuplot-nox).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "core/result.h"

namespace s2r {

struct SweepTable {
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows;
  std::vector<std::string> row_labels;  // optional first column (series name)

  Status write_csv(const std::filesystem::path& path) const;  // atomic
};

struct PlotSpec {
  std::string title, xlabel, ylabel;
  std::string x;                 // column name
  std::vector<std::string> y;    // column names, one line each
  bool by_label = false;         // one line per row label instead
  bool logx = false, logy = false;
};

// Draws `table` into `png` (atomic). Fails with a clear message when gnuplot
// is missing; the CSV is still there.
Status plot_png(const SweepTable& table, const PlotSpec& spec, const std::filesystem::path& png);

double median(std::vector<double> v);

}  // namespace s2r
