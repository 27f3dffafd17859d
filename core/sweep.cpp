#include "core/sweep.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

#include "core/atomic_file.h"
#include "core/shell.h"

namespace s2r {
namespace fs = std::filesystem;

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

Status SweepTable::write_csv(const fs::path& path) const {
  std::ostringstream s;
  s.precision(9);
  if (!row_labels.empty()) s << "series,";
  for (size_t i = 0; i < columns.size(); ++i) s << (i ? "," : "") << columns[i];
  s << "\n";
  for (size_t r = 0; r < rows.size(); ++r) {
    if (!row_labels.empty()) s << row_labels[r] << ",";
    for (size_t i = 0; i < rows[r].size(); ++i) s << (i ? "," : "") << rows[r][i];
    s << "\n";
  }
  return write_file_atomic(path, s.str());
}

namespace {

// A gnuplot single-quoted string: a quote inside is written twice.
std::string gp_quote(const std::string& text) {
  std::string out = "'";
  for (char c : text) out += c == '\'' ? std::string("''") : std::string(1, c);
  return out + "'";
}

}  // namespace

Status plot_png(const SweepTable& t, const PlotSpec& spec, const fs::path& png) {
  auto col = [&](const std::string& name) -> int {
    for (size_t i = 0; i < t.columns.size(); ++i)
      if (t.columns[i] == name) return static_cast<int>(i);
    return -1;
  };
  const int xc = col(spec.x);
  if (xc < 0) return fail("plot: no column '" + spec.x + "'");
  // Inline data blocks: one block per line of the plot.
  std::ostringstream script;
  script << "set terminal pngcairo size 900,560 font 'sans,10' noenhanced\n";
  script << "set title " << gp_quote(spec.title) << "\nset xlabel " << gp_quote(spec.xlabel) << "\nset ylabel "
         << gp_quote(spec.ylabel) << "\nset grid\nset key left top\n";
  if (spec.logx) script << "set logscale x\n";
  if (spec.logy) script << "set logscale y\n";
  std::vector<std::pair<std::string, std::vector<std::pair<double, double>>>> lines;
  if (spec.by_label) {
    std::vector<std::string> labels;
    for (const auto& l : t.row_labels)
      if (std::find(labels.begin(), labels.end(), l) == labels.end()) labels.push_back(l);
    const int yc = col(spec.y.at(0));
    if (yc < 0) return fail("plot: no column '" + spec.y.at(0) + "'");
    for (const auto& l : labels) {
      std::vector<std::pair<double, double>> pts;
      for (size_t r = 0; r < t.rows.size(); ++r)
        if (t.row_labels[r] == l) pts.emplace_back(t.rows[r][size_t(xc)], t.rows[r][size_t(yc)]);
      lines.emplace_back(l, pts);
    }
  } else {
    for (const auto& y : spec.y) {
      const int yc = col(y);
      if (yc < 0) return fail("plot: no column '" + y + "'");
      std::vector<std::pair<double, double>> pts;
      for (const auto& row : t.rows) pts.emplace_back(row[size_t(xc)], row[size_t(yc)]);
      lines.emplace_back(y, pts);
    }
  }
  for (size_t i = 0; i < lines.size(); ++i) {
    script << "$d" << i << " << EOD\n";
    for (const auto& [x, y] : lines[i].second) script << x << " " << y << "\n";
    script << "EOD\n";
  }
  script << "plot ";
  for (size_t i = 0; i < lines.size(); ++i)
    script << (i ? ", " : "") << "$d" << i << " using 1:2 with linespoints lw 2 title " << gp_quote(lines[i].first);
  script << "\n";
  return write_via_temp(png, [&](const fs::path& tmp) -> Status {
    const fs::path gp = tmp.string() + ".gp";
    {
      std::ofstream f(gp);
      f << "set output " << gp_quote(tmp.string()) << "\n" << script.str();
    }
    const ShellRun gnuplot = run_shell("gnuplot " + sh_quote(gp.string()) + " 2>&1");
    fs::remove(gp);
    if (gnuplot.code != 0) return fail("gnuplot failed (is gnuplot-nox installed?): " + gnuplot.output);
    return {};
  });
}

}  // namespace s2r
