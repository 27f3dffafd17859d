// A capture session (capture/session.h): session.json, then the journal of
// frames written after it (session.journal), as two parts of one input.
#include <cstdio>
#include <filesystem>

#include "capture/session.h"
#include "fuzz/fuzz_support.h"

namespace {
// Frame files as the seeds name them (color/NNNN.png, depth/NNNN.png,
// points/NNNN.ply), so loading goes past the existence check into the frames
// and the journal. Images are not decoded (check_images = false).
void make_frame_files(const s2r::fuzz::ScratchDir& dir) {
  char name[32];
  for (const char* kind : {"color", "depth", "points"}) {
    std::filesystem::create_directories(dir.path() / kind);
    for (int i = 0; i < 64; ++i) {
      std::snprintf(name, sizeof name, "%s/%04d.%s", kind, i, kind[0] == 'p' ? "ply" : "png");
      dir.write(name, "x");
    }
  }
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto& dir = s2r::fuzz::scratch();
  static const bool files = (make_frame_files(dir), true);
  (void)files;
  const auto parts = s2r::fuzz::split_parts(data, size);
  dir.write("session.json", parts[0]);
  if (parts.size() > 1)
    dir.write("session.journal", parts[1]);
  else
    dir.remove("session.journal");
  auto s = s2r::load_session(dir.path(), {.check_images = false});
  s2r::fuzz::report(s);
  if (s)
    for (const auto& f : s->frames) (void)s->color_intrinsics(f);
  return 0;
}
