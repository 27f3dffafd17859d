// A model (reconstruct/model.h): model.json, facets.bin, facet_cameras.bin and
// octree.bin as the parts of one input. Payloads of at least a header and a
// footer get their CRC-32 recomputed, so inputs reach the record checks behind
// the checksum (the checksum itself is covered by reconstruct_formats_test).
#include <zlib.h>

#include <cstring>

#include "fuzz/fuzz_support.h"
#include "reconstruct/model.h"

namespace {
std::string with_crc(std::string_view part) {
  std::string b(part);
  if (b.size() < 28) return b;
  const uint32_t c = static_cast<uint32_t>(::crc32(0L, reinterpret_cast<const Bytef*>(b.data()), static_cast<uInt>(b.size() - 4)));
  std::memcpy(b.data() + b.size() - 4, &c, 4);
  return b;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto& dir = s2r::fuzz::scratch();
  const auto parts = s2r::fuzz::split_parts(data, size);
  const char* names[] = {"model.json", "facets.bin", "facet_cameras.bin", "octree.bin"};
  for (size_t i = 0; i < 4; ++i) {
    if (i >= parts.size())
      dir.remove(names[i]);
    else
      dir.write(names[i], i == 0 ? std::string(parts[0]) : with_crc(parts[i]));
  }
  const auto loaded = s2r::load_model(dir.path());
  s2r::fuzz::report(loaded);
  return 0;
}
