// A capture session on disk (docs/formats.md, "Session"):
//
//   SESSION/session.json      header, devices, frames (format "s2r.session")
//   SESSION/session.journal   one JSON line per frame, appended + fsync'ed
//   SESSION/color/NNNN.png    8-bit colour
//   SESSION/depth/NNNN.png    16-bit depth, `unit_m` metres per count, 0 = none
//   SESSION/points/NNNN.ply   optional: scanner points (range scans)
//   SESSION/mask/NNNN.png     optional: 8-bit matte of the object (255 inside,
//                             fractional at its edges), e.g. an RGBA photo's alpha
//
// Frames are written file-then-rename, then journaled, then session.json is
// rewritten atomically, so a session killed at any instant loads (and
// resumes) with every completed frame and no half-written one.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/result.h"

namespace s2r {

inline constexpr int kSessionVersion = 1;

struct ColorSensor {
  std::string driver;  // "v4l2", "libcamera", "synth", "import", ...
  std::string device;  // node or model name
  std::string pixel_format;
  Intrinsics intrinsics;  // nominal (device or import); calibration refines it
  double exposure_us = 0;  // 0 = unknown / auto
  double gain = 0;
};

struct DepthSensor {
  std::string driver, device;
  Intrinsics intrinsics;
  double unit_m = 0.001;  // metres per depth count
  Eigen::Isometry3d color_from_depth = Eigen::Isometry3d::Identity();
  bool aligned_to_color = false;  // depth already resampled into the colour camera
};

struct TurntableInfo {
  std::string driver, device;
};

enum class Layout { kObjectCentre, kCameraCentre };

struct Frame {
  int index = 0;
  double table_angle_commanded_deg = 0;
  double table_angle_reported_deg = 0;
  int64_t timestamp_ns = 0;
  std::string color;   // relative path or empty
  std::string depth;   // relative path or empty
  std::string points;  // relative path or empty
  std::string mask;    // relative path or empty: the object's matte, same size as colour
  std::string source;  // original name (imports), e.g. "bun045.ply"
  double exposure_us = 0;
  std::optional<Eigen::Isometry3d> world_from_camera;  // given pose (imports)
  std::optional<Intrinsics> intrinsics;               // per-frame colour intrinsics
};

struct Session {
  std::filesystem::path root;
  std::string name;
  std::string source;  // "synth:fuzzy", "import:middlebury", "capture", ...
  Layout layout = Layout::kObjectCentre;
  std::optional<ColorSensor> color;
  std::optional<DepthSensor> depth;
  std::optional<TurntableInfo> turntable;
  std::vector<std::string> notes;
  std::vector<Frame> frames;
  // The colour the photos are composited on where the matte is below 255
  // (a data set's own background: white for NeRF-synthetic), RGB in [0, 1].
  // Empty: the photos show whatever was behind the object.
  std::optional<std::array<float, 3>> background;

  // Colour intrinsics of a frame: its own, else the colour sensor's.
  std::optional<Intrinsics> color_intrinsics(const Frame& f) const;
  std::filesystem::path path_of(const std::string& relative) const { return root / relative; }
};

struct SessionLoadOptions {
  bool check_images = true;  // open every image's header: exists, readable, size matches
};

// Loads and validates. Errors name the file and the field.
Result<Session> load_session(const std::filesystem::path& dir, SessionLoadOptions opts = {});

// Frame images (decoded fully: a truncated file is an error naming it).
Result<ImageU8> load_color(const Session& s, const Frame& f);
Result<ImageU16> load_depth(const Session& s, const Frame& f);
Result<ImageU8> load_mask(const Session& s, const Frame& f);  // 1 channel

// Writes session.json atomically (the journal is left as it is).
Status save_session_json(const Session& s);

// Writes frames as they come. Resuming continues after the last complete frame.
class SessionWriter {
 public:
  // New session: `dir` must not hold a session already.
  static Result<SessionWriter> create(Session header);
  // Existing session (load_session + continue at frames.size()).
  static Result<SessionWriter> resume(const std::filesystem::path& dir);

  // Writes images (file-then-rename), journals the frame, rewrites session.json.
  // `frame.index` must be next_index(); file names are filled in.
  Status add_frame(Frame frame, const ImageU8* color, const ImageU16* depth, const ImageU8* mask = nullptr);
  int next_index() const { return static_cast<int>(session_.frames.size()); }
  // Store frames without PNG compression (a live capture keeping up with its camera).
  void set_fast_writes(bool fast) { fast_ = fast; }
  const Session& session() const { return session_; }
  Session& mutable_header() { return session_; }  // devices/notes before frames

 private:
  explicit SessionWriter(Session s) : session_(std::move(s)) {}
  Session session_;
  bool fast_ = false;
};

std::string frame_file_name(int index, const char* ext);  // "0007.png"

}  // namespace s2r
