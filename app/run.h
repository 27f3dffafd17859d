// What the engine (`s2r-engine`) runs for each subcommand: one `run` per
// arguments type of app/args.h, returning the exit code (0 ok, 1 failure,
// 2 usage / not available); and the helpers the runs share.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "app/args.h"
#include "core/report.h"
#include "core/result.h"

namespace s2r::cli {

int run(const SynthArgs& a);  // app/cmd_data.cpp
int run(const ImportArgs& a);
int run(const InspectArgs& a);
int run(const DevicesArgs& a);
int run(const TurntableArgs& a);
int run(const CaptureArgs& a);
int run(const IntrinsicsArgs& a);
int run(const DepthCalibrationArgs& a);
int run(const AxisArgs& a);
int run(const MarkersArgs& a);
int run(const RegisterArgs& a);  // app/cmd_reconstruct.cpp
int run(const ReconstructArgs& a);
int run(const ExportArgs& a);
int run(const PreviewArgs& a);  // app/cmd_render.cpp
int run(const RenderArgs& a);
int run(const EvalArgs& a);
int run(const ViewArgs& a);
int run(const RaytraceArgs& a);
int run(const EnvmapArgs& a);
int run(const BenchArgs& a);    // app/cmd_bench.cpp
// app/cmd_bench_views.cpp.
int bench_views(const std::filesystem::path& out, int lego_views, const ViewsFit& fit, const std::vector<std::string>& scenes);
int run(const SummaryArgs& a);  // app/cmd_summary.cpp
int run(const BatchArgs& a);    // app/cmd_batch.cpp

// Print the report's brief line and write it to `path` (or OUT/report.json).
int finish(const Report& report, const std::filesystem::path& path);
int error(const std::string& message);
// "a,b,c" -> {"a", "b", "c"}
std::vector<std::string> comma_items(const std::string& s);
// A positive, finite length in metres, the whole token.
std::optional<double> positive_metres(const std::string& item);
// "white", "black" or "R,G,B" (0-255 levels each) -> RGB in [0, 1]; `flag`
// names the option in the error.
Result<std::array<float, 3>> parse_background(const std::string& s, const std::string& flag);
// "3,7,11" -> frame indices (>= 0); `flag` names the option in the error.
Result<std::vector<int>> frame_list(const std::string& s, const std::string& flag);

// Which flag sets which options field, for messages: a library names the
// field ("target_error_px: must be > 0"), the user reads the flag's name.
using FlagNames = std::vector<std::pair<std::string, std::string>>;  // field, flag
// `e`'s message with a leading "FIELD:" replaced by "FLAG:".
std::string in_flag_terms(const Error& e, const FlagNames& names);

}  // namespace s2r::cli
