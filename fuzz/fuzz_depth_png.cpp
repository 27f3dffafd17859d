// Depth frames: 16-bit greyscale PNGs read through libpng directly
// (core/image_io.h read_image_u16); any other image falls back to OpenImageIO.
#include "core/image_io.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = s2r::fuzz::scratch().write("depth.png", {reinterpret_cast<const char*>(data), size});
  s2r::fuzz::report(s2r::read_image_u16(path));
  return 0;
}
