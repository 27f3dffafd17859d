// Running a shell command and reading what it prints: gnuplot for the
// sweeps' plots, the bench's peers, the tests' other tools (validators,
// readers, the CLI itself).
#pragma once

#include <string>

namespace s2r {

// A POSIX shell single-quoted word: a quote inside ends the word, is
// escaped, and reopens it.
std::string sh_quote(const std::string& text);

struct ShellRun {
  int code = -1;       // the exit status; -1 when it could not run or did not exit
  std::string output;  // its standard output (add 2>&1 to the command for its errors too)
};

// Runs `command` with /bin/sh and waits for it.
ShellRun run_shell(const std::string& command);

}  // namespace s2r
