// The turntable's serial protocol (capture/serial_port.h, grbl_turntable.h):
// bytes from the board, split into lines in arbitrary chunks, each line
// classified as the driver does (ok, error:N, ALARM:N, banner, status report).
#include <cmath>
#include <cstdlib>

#include "capture/grbl_turntable.h"
#include "capture/serial_port.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  // The first byte picks how the stream is chunked (reads of 1..32 bytes) and the axis.
  const size_t chunk = 1 + data[0] % 32;
  const char axis = "XYZ"[data[0] / 32 % 3];
  s2r::LineSplitter lines(64);
  const std::string_view bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
  for (size_t at = 0; at < bytes.size(); at += chunk) {
    lines.feed(bytes.substr(at, chunk));
    while (auto line = lines.next()) {
      if (line->size() > 64) std::abort();  // the splitter's bound
      for (char c : *line)
        if (c < 0x20 || c >= 0x7f) std::abort();  // only printable ASCII gets through
      const auto r = s2r::classify_grbl_reply(*line, axis);
      if ((r.kind == s2r::GrblReply::kError || r.kind == s2r::GrblReply::kAlarm) && r.code > 9999) std::abort();
      if (r.kind == s2r::GrblReply::kStatus && (r.status.state.empty() || !std::isfinite(r.status.position)))
        std::abort();
      (void)s2r::grbl_error_meaning(r.code);
      (void)s2r::grbl_alarm_meaning(r.code);
    }
  }
  return 0;
}
