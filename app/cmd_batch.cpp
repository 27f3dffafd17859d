// s2r batch: many captures through the same steps (app/batch.h), here with
// --jobs or as a Slurm job array with --slurm; --status reads what finished.
#include <cstdio>
#include <filesystem>

#include "app/batch.h"
#include "app/run.h"

namespace s2r::cli {
namespace {
namespace fs = std::filesystem;

void print_rows(const std::vector<batch::Row>& rows) {
  for (const auto& r : rows) {
    std::string psnr;
    for (const auto& [m, v] : r.psnr) {
      char buf[64];
      std::snprintf(buf, sizeof buf, " %s %.2f dB", m.c_str(), v);
      psnr += buf;
    }
    std::printf("  %-28s %-10s %-8s %8.1f s %7.0f MB%s%s\n", r.name.c_str(), r.kind.c_str(), r.state.c_str(), r.seconds,
                r.peak_mb, psnr.empty() ? "" : ",", psnr.c_str());
    if (r.state == "failed") std::printf("    at %s: %s\n", r.failed_step.c_str(), r.message.c_str());
  }
}

// Writes the page and prints the table; 0 all done, 1 failures, 3 unfinished.
int summarise(const fs::path& results, const batch::Manifest& m) {
  const auto rows = batch::collect(results, m);
  if (auto st = batch::write_summary(results, m, rows); !st) return error(st.error().message);
  int failed = 0, unfinished = 0;
  for (const auto& r : rows) {
    failed += r.state == "failed";
    unfinished += r.state == "pending" || r.state == "running";
  }
  std::printf("batch: %zu captures, %zu done, %d failed, %d not finished\n", rows.size(),
              rows.size() - failed - unfinished, failed, unfinished);
  print_rows(rows);
  std::printf("batch: summary %s\n", (results / "index.html").c_str());
  return failed ? 1 : unfinished ? 3 : 0;
}

}  // namespace

int run(const BatchArgs& a) {
  if (!a.status.empty()) {
    auto m = batch::read_manifest(a.status);
    if (!m) return error("--status: " + m.error().message + " (is it a batch's results folder?)");
    return summarise(a.status, *m);
  }
  if (a.out.empty()) return error("--out RESULTS is required (or --status RESULTS)");
  const fs::path results = a.out;
  std::error_code ec;
  const fs::path s2r = fs::read_symlink("/proc/self/exe", ec).parent_path() / "s2r";
  if (ec) return error("cannot find this program's folder: " + ec.message());
  batch::RunOptions ro;
  ro.s2r = s2r;
  ro.jobs = a.jobs;
  ro.retry_failed = a.retry_failed;

  if (a.task >= 0) {
    auto m = batch::read_manifest(results);
    if (!m) return error(m.error().message);
    if (a.tasks <= 0 || a.task >= a.tasks) return error("--task I needs --tasks N with 0 <= I < N");
    const auto mine = batch::task_captures(a.task, a.tasks, static_cast<int>(m->captures.size()));
    ro.jobs = 1;
    return batch::run_captures(results, *m, mine, ro) ? 1 : 0;
  }

  const bool have_manifest = fs::exists(results / "batch.json");
  batch::Manifest m;
  if (a.root.empty()) {
    if (!have_manifest) return error("give ROOT, the folder of captures ('" + results.string() + "' holds no batch yet)");
    auto old = batch::read_manifest(results);
    if (!old) return error(old.error().message);
    m = *old;
  } else {
    if (fs::exists(results, ec) && !have_manifest && !fs::is_empty(results, ec))
      return error("'" + results.string() + "' is not empty and holds no batch (batch.json): choose a new folder");
    if (have_manifest) {
      auto old = batch::read_manifest(results);
      if (!old) return error(old.error().message);
      if (fs::weakly_canonical(old->root, ec) != fs::weakly_canonical(a.root, ec))
        return error("'" + results.string() + "' holds the batch of " + old->root.string() + ", not " + a.root +
                     ": choose another --out");
    }
    m.root = a.root;
    auto caps = batch::discover(a.root);
    if (!caps) return error(caps.error().message);
    m.captures = *caps;
    auto steps = batch::parse_steps(a.steps);
    if (!steps) return error(steps.error().message);
    m.steps = *steps;
    auto options = batch::load_options(a.options);
    if (!options) return error(options.error().message);
    m.options = *options;
  }
  if (auto st = batch::write_manifest(results, m); !st) return error(st.error().message);
  std::printf("batch: %zu captures under %s, steps %s\n", m.captures.size(), m.root.c_str(),
              [&] {
                std::string s;
                for (const auto& x : m.steps) s += (s.empty() ? "" : ",") + x;
                return s;
              }().c_str());
  for (const auto& c : m.captures) std::printf("  %-28s %-10s %s\n", c.name.c_str(), c.kind.c_str(), c.path.c_str());

  if (a.slurm) {
    batch::SlurmOptions so;
    so.cpus_per_task = a.cpus_per_task;
    so.mem_mb = a.mem_mb;
    so.time = a.time;
    so.partition = a.partition;
    so.sbatch_args = a.sbatch_args;
    so.sbatch = a.sbatch;
    auto sub = batch::submit_slurm(results, m, s2r, so);
    if (!sub) return error(sub.error().message);
    std::printf("batch: submitted job array %s (%d tasks, %.0f MB, %s min each) and summary job %s (afterany)\n",
                sub->array_job.c_str(), sub->tasks, sub->mem_mb, sub->time.c_str(), sub->summary_job.c_str());
    std::printf("batch: s2r batch --status %s reads what finished\n", results.c_str());
    return 0;
  }
  std::vector<int> all(m.captures.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
  batch::run_captures(results, m, all, ro);
  return summarise(results, m);
}

}  // namespace s2r::cli
