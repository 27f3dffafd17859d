// Scenes of the synthetic turntable rig (`s2r synth`): geometry,
// appearance, camera placement and light. Rendering lives in synth_rig.cpp.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "capture/session.h"
#include "core/mesh.h"
#include "core/result.h"

namespace s2r::synth {

enum Label : uint8_t { kNothing = 0, kSurface = 1, kStrand = 2 };
enum class Texture { kPatches, kWalls, kPlain, kChessboard };

struct Surface {
  Mesh mesh;  // with vertex normals, in the world frame
  Texture texture = Texture::kPatches;
};

// Thin round curves (Embree linear round curves): control points with radius,
// and for each segment the index of its first control point.
struct Strands {
  std::vector<Eigen::Vector4f> points;  // x y z radius
  std::vector<uint32_t> segments;
  std::vector<Eigen::Vector3f> colors;  // per segment
};

struct Scene {
  std::string name;
  Layout layout = Layout::kObjectCentre;
  std::vector<Surface> surfaces;
  Strands strands;
  // Pose of the colour camera in the table frame at table angle 0.
  Eigen::Isometry3d table_from_camera = Eigen::Isometry3d::Identity();
  Eigen::Vector3d light_dir_lab = Eigen::Vector3d::UnitZ();  // towards the light
  double far_m = 10;
  // kChessboard surfaces: the board frame (x along columns, y along rows, z
  // the printed side's normal) and the squares.
  Eigen::Isometry3d world_from_board = Eigen::Isometry3d::Identity();
  int board_squares_x = 10, board_squares_y = 7;
  double board_square_m = 0.02;
  // Camera wobble (the "board_wobble" scene): per view the camera also swings
  // in elevation about `wobble_centre` and rolls, by up to this many degrees,
  // as a hand-held board would vary its tilt. Not a turntable motion.
  double camera_wobble_deg = 0;
  Eigen::Vector3d wobble_centre = Eigen::Vector3d::Zero();
};

// Names: "bunny" (textured Stanford bunny), "fuzzy" (core + thousands of thin
// strands), "room" (camera in the middle of a furnished room), "blob" (a
// closed textured object needing no external data), "vase" (a textured surface
// of revolution about the table axis: the symmetric case), "board" (a printed
// chessboard standing on the table, 9x6 inner corners of 20 mm, for calibration),
// "board_wobble" (the same board seen from views that also vary in elevation and
// roll: intrinsics data, not a turntable).
Result<Scene> make_scene(const std::string& name, uint64_t seed,
                         const std::filesystem::path& data_dir);
std::vector<std::string> scene_names();

}  // namespace s2r::synth
