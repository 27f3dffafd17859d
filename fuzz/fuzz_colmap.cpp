// COLMAP sparse models (capture/colmap_model.h): the input's three parts are
// cameras, images and points3D, read once as text and once as binary files.
#include "capture/colmap_model.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto parts = s2r::fuzz::split_parts(data, size);
  auto& dir = s2r::fuzz::scratch();
  for (const char* ext : {"txt", "bin"}) {
    const char* names[] = {"cameras", "images", "points3D"};
    const std::filesystem::path folder = dir.path() / ext;
    std::error_code ec;
    std::filesystem::create_directories(folder, ec);
    for (size_t i = 0; i < 3; ++i) {
      const std::string name = std::string(ext) + "/" + names[i] + "." + ext;
      dir.write(name, i < parts.size() ? parts[i] : std::string_view{});
    }
    s2r::fuzz::report(s2r::read_colmap_model(folder));
  }
  return 0;
}
