#include "capture/capture_session.h"

#include <cmath>
#include <limits>
#include <optional>

#include "core/progress.h"

namespace s2r {
namespace fs = std::filesystem;

Result<Report> run_capture(CaptureDevices& dev, const CaptureOptions& o, const std::atomic<bool>* stop) {
  Stopwatch clock;
  if (o.steps < 1 || o.steps > 3600) return fail(ErrorCode::invalid, "steps: must be in 1..3600");
  if (!dev.color || !dev.table) return fail("a capture needs a colour camera and a turntable");
  Report rep;
  rep.stage = "capture";
  rep.params["steps"] = double(o.steps);
  rep.params["out"] = o.out.string();

  std::optional<SessionWriter> writer;
  const bool exists = fs::exists(o.out / "session.json");
  if (exists && !o.resume)
    return fail("'" + o.out.string() + "' already holds a session; resume it to continue");
  if (exists) {
    auto w = SessionWriter::resume(o.out);
    if (!w) return std::unexpected(w.error());
    writer.emplace(std::move(*w));
    rep.skipped["frames_already_captured"] = writer->next_index();
    // Opening the port resets a GRBL board, which forgets its position: the
    // table stands where the last complete frame left it, so declare that
    // position (G92) rather than move.
    const auto& frames = writer->session().frames;
    const double last = frames.empty() ? 0.0 : frames.back().table_angle_reported_deg;
    if (auto st = dev.table->set_position(last); !st) return std::unexpected(with_context(st.error(), "resuming"));
    if (!frames.empty())
      rep.warnings.push_back("resumed after frame " + std::to_string(frames.back().index) +
                             "; the table is assumed to stand at " + std::to_string(last) +
                             " deg (turn it back by hand if it was moved)");
  } else {
    Session h = dev.header;
    h.root = o.out;
    if (h.name.empty()) h.name = o.out.filename().string();
    if (h.source.empty()) h.source = "capture";
    h.notes.push_back("plan: " + std::to_string(o.steps) + " steps of " + std::to_string(360.0 / o.steps) + " deg");
    auto w = SessionWriter::create(std::move(h));
    if (!w) return std::unexpected(w.error());
    writer.emplace(std::move(*w));
    if (auto st = dev.table->home(); !st) return std::unexpected(with_context(st.error(), "homing the turntable"));
  }
  writer->set_fast_writes(o.fast_writes);
  if (writer->next_index() >= o.steps) {
    rep.seconds = clock.seconds();
    rep.counts["frames"] = writer->next_index();
    rep.warnings.push_back("session already complete");
    return rep;
  }

  if (auto st = dev.color->start(); !st) return std::unexpected(st.error());
  if (dev.depth)
    if (auto st = dev.depth->start(); !st) return std::unexpected(st.error());

  double worst_angle = 0, sum_dt = 0;
  int written = 0, dropped = 0, paired = 0, clock_mismatches = 0;
  Progress progress("capture", static_cast<size_t>(o.steps));
  progress.tick(static_cast<size_t>(writer->next_index()));
  for (int i = writer->next_index(); i < o.steps; ++i) {
    if (stop && stop->load()) {
      progress.done();
      return fail("interrupted after " + std::to_string(i) + " of " + std::to_string(o.steps) +
                  " frames; every written frame is complete: resume the session to continue");
    }
    const std::string at = "frame " + std::to_string(i) + ": ";
    const double angle = 360.0 * i / o.steps;
    if (auto st = dev.table->move_to(angle); !st) return std::unexpected(with_context(st.error(), at + "turntable"));
    auto reported = dev.table->position();
    if (!reported) return std::unexpected(with_context(reported.error(), at + "turntable"));
    for (int k = 0; k < o.flush_frames; ++k)
      if (auto f = dev.color->grab(); !f) return std::unexpected(with_context(f.error(), at + "colour camera"));
    auto color = dev.color->grab();
    if (!color) return std::unexpected(with_context(color.error(), at + "colour camera"));
    dropped += static_cast<int>(color->dropped_before);
    std::optional<CapturedFrame> depth;
    if (dev.depth) {
      double best = std::numeric_limits<double>::infinity();
      std::optional<CapturedFrame> last;
      for (int k = 0; k < std::max(1, o.depth_frames); ++k) {
        auto d = dev.depth->grab();
        if (!d) return std::unexpected(with_context(d.error(), at + "depth camera"));
        // In double: a clock that jumped must not overflow the difference.
        const double dt = std::abs(double(d->timestamp_ns) - double(color->timestamp_ns)) * 1e-9;
        if (dt <= o.max_pair_dt_s && dt < best) {
          best = dt;
          depth = std::move(*d);
        } else {
          last = std::move(*d);
        }
      }
      if (depth) {
        sum_dt += best * 1e3;
        ++paired;
      } else {
        depth = std::move(last);
        ++clock_mismatches;
      }
    }
    Frame f;
    f.index = i;
    f.table_angle_commanded_deg = angle;
    f.table_angle_reported_deg = *reported;
    f.timestamp_ns = color->timestamp_ns;
    if (auto st = writer->add_frame(f, &color->rgb, depth ? &depth->depth : nullptr); !st)
      return std::unexpected(with_context(st.error(), at + "writing"));
    worst_angle = std::max(worst_angle, std::abs(*reported - angle));
    ++written;
    progress.tick();
  }
  progress.done();
  dev.color->stop();
  if (dev.depth) dev.depth->stop();
  rep.seconds = clock.seconds();
  rep.counts["frames"] = o.steps;
  rep.counts["frames_written"] = written;
  rep.counts["camera_frames_dropped"] = dropped;
  rep.errors["max_table_angle_error_deg"] = worst_angle;
  if (dev.depth) rep.counts["depth_clock_mismatches"] = clock_mismatches;
  if (dev.depth && paired) rep.errors["mean_depth_color_dt_ms"] = sum_dt / paired;
  return rep;
}

}  // namespace s2r
