// Small helpers of the HTML pages the CLI writes (s2r summary, s2r batch's index).
#pragma once

#include <cstdio>
#include <string>

namespace s2r::html {

// Text safe inside an element or a quoted attribute (either quote).
inline std::string escape(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (char c : s) {
    if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '&') out += "&amp;";
    else if (c == '"') out += "&quot;";
    else if (c == '\'') out += "&#39;";
    else out += c;
  }
  return out;
}

// A figure for a table cell: four significant digits.
inline std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

}  // namespace s2r::html
