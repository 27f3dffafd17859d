// Subcommand registration for the s2r CLI. Each cmd_*.cpp adds its
// subcommands to the app and returns the exit code through `run`.
#pragma once

#include <CLI/CLI.hpp>

#include <filesystem>
#include <functional>
#include <optional>
#include <utility>
#include <string>
#include <vector>

#include "core/report.h"
#include "core/result.h"

namespace s2r::cli {

// Exit codes: 0 ok, 1 failure, 2 usage / not available.
using Runner = std::function<int()>;
void set_runner(Runner r);

void add_data_commands(CLI::App& app);    // synth, import, devices, capture, calibrate
void add_reconstruct_commands(CLI::App& app);  // register, reconstruct
void add_render_commands(CLI::App& app);  // preview, render, eval, view, raytrace, envmap
void add_bench_commands(CLI::App& app);   // bench
void add_summary_command(CLI::App& app);  // summary

// Print the report's brief line and write it to `path` (or OUT/report.json).
int finish(const Report& report, const std::filesystem::path& path);
int error(const std::string& message);
// "a,b,c" -> {"a", "b", "c"}
std::vector<std::string> comma_items(const std::string& s);
// A positive, finite length in metres, the whole token.
std::optional<double> positive_metres(const std::string& item);
// "3,7,11" -> frame indices (>= 0); `flag` names the option in the error.
Result<std::vector<int>> frame_list(const std::string& s, const std::string& flag);

// Which flag sets which options field, for messages: a library names the
// field ("target_error_px: must be > 0"), the user reads the flag's name.
using FlagNames = std::vector<std::pair<std::string, std::string>>;  // field, flag
// `e`'s message with a leading "FIELD:" replaced by "FLAG:".
std::string in_flag_terms(const Error& e, const FlagNames& names);

}  // namespace s2r::cli
