// Stanford .conf (capture/stanford_conf.h): "camera" and "bmesh" lines.
#include "capture/stanford_conf.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = s2r::fuzz::scratch().write("scan.conf", {reinterpret_cast<const char*>(data), size});
  const auto loaded = s2r::read_stanford_conf(path);
  s2r::fuzz::report(loaded);
  return 0;
}
