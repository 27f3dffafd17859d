// calibration.json (calibrate/calibration.h): intrinsics, depth-to-colour,
// turntable axis, measured table angles.
#include <cstdlib>

#include "calibrate/calibration.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto& dir = s2r::fuzz::scratch();
  const auto path = dir.write("calibration.json", {reinterpret_cast<const char*>(data), size});
  auto c = s2r::load_calibration(path);
  s2r::fuzz::report(c);
  if (c) {
    // What the pipeline asks of a loaded calibration must not trip either.
    const auto pose = c->world_from_camera_at(30.0, s2r::Layout::kObjectCentre);
    if (!pose.matrix().allFinite()) std::abort();  // a loaded axis gives a finite pose
  }
  return 0;
}
