// The s2r command line, shared by the front (`s2r`) and the engine
// (`s2r-engine`): every subcommand with its flags bound to its arguments
// (app/args.h). Nothing here runs a stage, so the front links no stage
// library and starts at once; the engine runs what was chosen (app/run.h).
#pragma once

#include <CLI/CLI.hpp>

#include <optional>

#include "app/args.h"

namespace s2r::cli {

// The whole command line: the description, -q/--quiet into `quiet`, and every
// subcommand; the parse sets `chosen` to the subcommand it selects.
void add_commands(CLI::App& app, Chosen& chosen, bool& quiet);
// The command line parsed into `chosen` and `quiet`; a help page or a usage
// error is printed here and its exit code returned.
std::optional<int> parse_command_line(int argc, char** argv, Chosen& chosen, bool& quiet);

void add_data_commands(CLI::App& app, Chosen& chosen);         // synth, import, inspect, devices, capture, calibrate
void add_reconstruct_commands(CLI::App& app, Chosen& chosen);  // register, reconstruct
void add_render_commands(CLI::App& app, Chosen& chosen);       // preview, render, eval, view, raytrace, envmap

}  // namespace s2r::cli
