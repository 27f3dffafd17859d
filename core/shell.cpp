#include "core/shell.h"

#include <sys/wait.h>

#include <array>
#include <cstdio>

namespace s2r {

std::string sh_quote(const std::string& text) {
  std::string out = "'";
  for (char c : text) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

ShellRun run_shell(const std::string& command) {
  ShellRun r;
  FILE* p = ::popen(command.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  while (std::fgets(buf.data(), int(buf.size()), p)) r.output += buf.data();
  const int st = ::pclose(p);
  r.code = st != -1 && WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

}  // namespace s2r
