// PLY scans and meshes (core/mesh.h, read through PCL's PLY reader).
#include "core/mesh.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = s2r::fuzz::scratch().write("scan.ply", {reinterpret_cast<const char*>(data), size});
  s2r::fuzz::report(s2r::read_ply_points(path));
  s2r::fuzz::report(s2r::read_ply_mesh(path));
  return 0;
}
