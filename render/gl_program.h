// Shader programs: compile + link with the driver's log in the error.
#pragma once

#include <string>

#include "core/result.h"

namespace s2r {

class GlProgram {
 public:
  static Result<GlProgram> build(const std::string& vertex_src, const std::string& fragment_src);
  GlProgram(GlProgram&&) noexcept;
  GlProgram& operator=(GlProgram&&) noexcept;
  GlProgram(const GlProgram&) = delete;
  ~GlProgram();
  unsigned id() const { return id_; }
  int uniform(const char* name) const;

 private:
  GlProgram() = default;
  unsigned id_ = 0;
};

}  // namespace s2r
