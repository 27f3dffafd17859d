#include "render/gl_program.h"

#include <epoxy/gl.h>

#include <utility>

namespace s2r {

namespace {
Result<GLuint> compile(GLenum type, const std::string& src) {
  GLuint s = glCreateShader(type);
  const char* p = src.c_str();
  glShaderSource(s, 1, &p, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[2048] = {};
    glGetShaderInfoLog(s, sizeof log, nullptr, log);
    glDeleteShader(s);
    return fail(std::string(type == GL_VERTEX_SHADER ? "vertex" : "fragment") + " shader: " + log);
  }
  return s;
}
}  // namespace

Result<GlProgram> GlProgram::build(const std::string& vs, const std::string& fs) {
  auto v = compile(GL_VERTEX_SHADER, vs);
  if (!v) return std::unexpected(v.error());
  auto f = compile(GL_FRAGMENT_SHADER, fs);
  if (!f) {
    glDeleteShader(*v);
    return std::unexpected(f.error());
  }
  GlProgram prog;
  prog.id_ = glCreateProgram();
  glAttachShader(prog.id_, *v);
  glAttachShader(prog.id_, *f);
  glLinkProgram(prog.id_);
  glDeleteShader(*v);
  glDeleteShader(*f);
  GLint ok = 0;
  glGetProgramiv(prog.id_, GL_LINK_STATUS, &ok);
  if (!ok) {
    char log[2048] = {};
    glGetProgramInfoLog(prog.id_, sizeof log, nullptr, log);
    return fail(std::string("shader link: ") + log);
  }
  return prog;
}

GlProgram::GlProgram(GlProgram&& o) noexcept { *this = std::move(o); }
GlProgram& GlProgram::operator=(GlProgram&& o) noexcept {
  std::swap(id_, o.id_);
  return *this;
}
GlProgram::~GlProgram() {
  if (id_) glDeleteProgram(id_);
}
int GlProgram::uniform(const char* name) const { return glGetUniformLocation(id_, name); }

}  // namespace s2r
