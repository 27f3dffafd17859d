#include "app/commands.h"

namespace s2r::cli {
void add_bench_commands(CLI::App& app) { add_not_yet(app, "bench", "Error-vs-time sweeps", "foundation"); }
}  // namespace s2r::cli
