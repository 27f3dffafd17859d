// s2r summary FOLDER: one page a user can open after a run. Collects every
// report.json under FOLDER (stage, seconds, errors, what was skipped) into a
// table, draws held-out error against frame time from every eval.csv, and
// links every PNG: FOLDER/index.html and FOLDER/index.md.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "app/run.h"
#include "app/html.h"
#include "core/atomic_file.h"
#include "core/json_fields.h"
#include "core/sweep.h"

namespace s2r::cli {
namespace {
namespace fs = std::filesystem;

struct StageRow {
  std::string folder, stage;
  double seconds = 0;
  std::vector<std::pair<std::string, double>> errors, skipped;
  std::vector<std::string> warnings;
};

using html::number;

// The headline errors: per-frame copies left out, at most 8.
std::vector<std::pair<std::string, double>> headline(const nlohmann::json& errors) {
  std::vector<std::pair<std::string, double>> out;
  if (!errors.is_object()) return out;
  for (const auto& [k, v] : errors.items()) {
    if (k.find("_frame_") != std::string::npos || !v.is_number()) continue;
    out.emplace_back(k, v.get<double>());
    if (out.size() == 8) break;
  }
  return out;
}

// eval.csv: frame, held_out, mask_pixels, then psnr_db_M, ssim_M, coverage_M, frame_ms_M per method M.
Status plot_eval(const fs::path& csv, const fs::path& png) {
  std::ifstream in(csv);
  std::string line;
  if (!std::getline(in, line)) return fail("'" + csv.string() + "' is empty");
  std::vector<std::string> cols = comma_items(line);
  std::vector<std::string> methods;
  for (const auto& c : cols)
    if (c.rfind("psnr_db_", 0) == 0) methods.push_back(c.substr(8));
  SweepTable t;
  t.columns = {"frame_ms", "psnr_db"};
  while (std::getline(in, line)) {
    const auto cells = comma_items(line);
    if (cells.size() != cols.size()) continue;
    auto value = [&](const std::string& name) {
      const auto it = std::find(cols.begin(), cols.end(), name);
      return it == cols.end() ? std::nan("") : std::strtod(cells[size_t(it - cols.begin())].c_str(), nullptr);
    };
    for (const auto& m : methods) {
      const double ms = value("frame_ms_" + m), db = value("psnr_db_" + m);
      if (!std::isfinite(ms) || !std::isfinite(db)) continue;
      t.rows.push_back({ms, db});
      t.row_labels.push_back(m);
    }
  }
  if (t.rows.empty()) return fail("'" + csv.string() + "' has no frames");
  PlotSpec spec{"held-out PSNR against frame time (each point a frame)", "frame time (ms)", "PSNR (dB)",
                "frame_ms", {"psnr_db"}, true};
  return plot_png(t, spec, png);
}

int run_summary(const fs::path& folder, const std::string& title) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return error("'" + folder.string() + "': folder not found");
  std::vector<fs::path> reports, csvs;
  for (fs::recursive_directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_symlink(ec)) continue;
    if (it->path().filename() == "report.json") reports.push_back(it->path());
    if (it->path().filename() == "eval.csv") csvs.push_back(it->path());
  }
  for (const auto& csv : csvs)
    if (auto st = plot_eval(csv, csv.parent_path() / "psnr_vs_frame_time.png"); !st)
      std::fprintf(stderr, "warning: %s\n", st.error().message.c_str());
  // Results, not inputs: a session's frames (a folder holding session.json)
  // and a model's camera textures are left out.
  std::vector<fs::path> pngs;
  for (fs::recursive_directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_directory(ec) && (fs::exists(it->path() / "session.json", ec) || it->path().filename() == "cameras")) {
      it.disable_recursion_pending();
      continue;
    }
    if (it->path().extension() == ".png" && !it->is_symlink(ec)) pngs.push_back(it->path());
  }
  std::sort(reports.begin(), reports.end());
  std::sort(pngs.begin(), pngs.end());

  std::vector<StageRow> rows;
  double total = 0;
  for (const auto& r : reports) {
    auto j = parse_json_file(r);
    if (!j || !j->is_object()) {
      std::fprintf(stderr, "warning: %s\n", j ? (r.string() + ": not a report").c_str() : j.error().message.c_str());
      continue;
    }
    StageRow row;
    row.folder = fs::relative(r.parent_path(), folder, ec).string();
    row.stage = j->value("stage", std::string("?"));
    row.seconds = (*j)["seconds"].is_number() ? (*j)["seconds"].get<double>() : 0;
    row.errors = headline((*j)["errors"]);
    if ((*j)["skipped"].is_object())
      for (const auto& [k, v] : (*j)["skipped"].items())
        if (v.is_number() && v.get<double>() != 0 && k.find("_frame_") == std::string::npos)
          row.skipped.emplace_back(k, v.get<double>());
    if ((*j)["warnings"].is_array())
      for (const auto& w : (*j)["warnings"])
        if (w.is_string()) row.warnings.push_back(w.get<std::string>());
    if (row.folder != ".") total += row.seconds;
    rows.push_back(std::move(row));
  }

  std::ostringstream md, html;
  md << "# " << title << "\n\nEvery stage's report (`report.json`): its seconds, its errors, what it left out.\n\n"
     << "| folder | stage | seconds | errors | skipped |\n|---|---|---|---|---|\n";
  html << "<!doctype html><html><head><meta charset='utf-8'><title>" << html::escape(title)
       << "</title><style>body{font-family:sans-serif;margin:2em;max-width:1400px}table{border-collapse:collapse}"
          "td,th{border:1px solid #ccc;padding:4px 8px;vertical-align:top;font-size:13px}img{max-width:100%;"
          "border:1px solid #ddd}figure{margin:1em 0}</style></head><body><h1>"
       << html::escape(title) << "</h1><p>Every stage's report (report.json): its seconds, its errors, what it left out. "
       << "Stages together: " << number(total) << " s.</p><table><tr><th>folder</th><th>stage</th><th>seconds</th>"
       << "<th>errors</th><th>skipped</th><th>warnings</th></tr>";
  for (const auto& r : rows) {
    std::string errs, skips;
    for (const auto& [k, v] : r.errors) errs += k + " " + number(v) + "; ";
    for (const auto& [k, v] : r.skipped) skips += k + " " + number(v) + "; ";
    md << "| " << r.folder << " | " << r.stage << " | " << number(r.seconds) << " | " << errs << " | " << skips << " |\n";
    html << "<tr><td><a href='" << html::escape(r.folder) << "/report.json'>" << html::escape(r.folder) << "</a></td><td>"
         << html::escape(r.stage) << "</td><td>" << number(r.seconds) << "</td><td>" << html::escape(errs) << "</td><td>"
         << html::escape(skips) << "</td><td>";
    for (const auto& w : r.warnings) html << html::escape(w) << "<br>";
    html << "</td></tr>";
  }
  md << "\nStages together: " << number(total) << " s.\n\n## Images\n\n";
  html << "</table><h2>Images</h2>";
  for (const auto& p : pngs) {
    const std::string rel = fs::relative(p, folder, ec).string();
    md << "### " << rel << "\n\n![" << rel << "](" << rel << ")\n\n";
    html << "<figure><figcaption>" << html::escape(rel) << "</figcaption><a href='" << html::escape(rel) << "'><img src='"
         << html::escape(rel) << "'></a></figure>";
  }
  html << "</body></html>\n";
  if (auto st = write_file_atomic(folder / "index.md", md.str()); !st) return error(st.error().message);
  if (auto st = write_file_atomic(folder / "index.html", html.str()); !st) return error(st.error().message);
  std::fprintf(stderr, "summary: %zu reports, %zu images, %zu error-vs-time plots from eval.csv: %s\n", rows.size(),
               pngs.size(), csvs.size(), (folder / "index.html").c_str());
  return 0;
}

}  // namespace

int run(const SummaryArgs& a) { return run_summary(a.folder, a.title); }

}  // namespace s2r::cli
