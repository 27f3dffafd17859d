// poses.json (reconstruct/poses.h): the registered pose of every view.
#include "fuzz/fuzz_support.h"
#include "reconstruct/poses.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = s2r::fuzz::scratch().write("poses.json", {reinterpret_cast<const char*>(data), size});
  const auto loaded = s2r::load_poses(path);
  s2r::fuzz::report(loaded);
  return 0;
}
