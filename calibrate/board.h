// Calibration boards and their detection in images (OpenCV): chessboards
// (inner-corner grid) and ChArUco boards (chessboard + ArUco markers, robust
// to partial views).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/result.h"

namespace s2r {

struct BoardSpec {
  enum class Kind { kChessboard, kCharuco } kind = Kind::kChessboard;
  int cols = 9, rows = 6;       // chessboard: inner corners; ChArUco: squares
  double square_m = 0.025;
  double marker_m = 0.0;        // ChArUco marker side
  std::string dictionary = "DICT_6X6_250";

  // "chessboard:9x6:0.025" or "charuco:5x7:0.04:0.02[:DICT_6X6_250]"
  static Result<BoardSpec> parse(const std::string& text);
  std::string to_string() const;
};

struct BoardDetection {
  bool found = false;
  std::vector<Eigen::Vector2f> image_points;   // sub-pixel corners
  std::vector<Eigen::Vector3f> board_points;   // the same corners on the board (z = 0), metres
  std::vector<int> ids;                        // corner ids (ChArUco); row-major index for chessboards
};

// Sub-pixel refined detection; `found` false when the board is not seen.
Result<BoardDetection> detect_board(const ImageU8& image, const BoardSpec& board);

}  // namespace s2r
