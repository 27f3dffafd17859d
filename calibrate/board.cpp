#include "calibrate/board.h"

#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

namespace s2r {

Result<BoardSpec> BoardSpec::parse(const std::string& text) {
  std::vector<std::string> parts;
  std::stringstream ss(text);
  for (std::string p; std::getline(ss, p, ':');) parts.push_back(p);
  BoardSpec b;
  auto bad = [&](const std::string& why) {
    return fail("board '" + text + "': " + why +
                " (expected chessboard:COLSxROWS:SQUARE_M or charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT])");
  };
  if (parts.size() < 3) return bad("too few fields");
  if (parts[0] == "chessboard") b.kind = Kind::kChessboard;
  else if (parts[0] == "charuco") b.kind = Kind::kCharuco;
  else return bad("unknown board kind '" + parts[0] + "'");
  if (std::sscanf(parts[1].c_str(), "%dx%d", &b.cols, &b.rows) != 2 || b.cols < 2 || b.rows < 2)
    return bad("size must be COLSxROWS with both >= 2");
  try {
    b.square_m = std::stod(parts[2]);
    if (b.kind == Kind::kCharuco) {
      if (parts.size() < 4) return bad("ChArUco needs the marker size");
      b.marker_m = std::stod(parts[3]);
      if (parts.size() >= 5) b.dictionary = parts[4];
    }
  } catch (...) {
    return bad("sizes must be numbers in metres");
  }
  if (!(b.square_m > 0) || (b.kind == Kind::kCharuco && !(b.marker_m > 0 && b.marker_m < b.square_m)))
    return bad("sizes must be > 0 and the marker smaller than the square");
  return b;
}

std::string BoardSpec::to_string() const {
  std::ostringstream s;
  s << (kind == Kind::kChessboard ? "chessboard:" : "charuco:") << cols << "x" << rows << ":" << square_m;
  if (kind == Kind::kCharuco) s << ":" << marker_m << ":" << dictionary;
  return s.str();
}

namespace {

cv::Mat grey_of(const ImageU8& im) {
  cv::Mat m(im.height, im.width, CV_MAKETYPE(CV_8U, im.channels), const_cast<uint8_t*>(im.data.data())), g;
  if (im.channels == 1) g = m.clone();
  else cv::cvtColor(m, g, im.channels == 4 ? cv::COLOR_RGBA2GRAY : cv::COLOR_RGB2GRAY);
  return g;
}

Result<int> dictionary_id(const std::string& name) {
  static const std::map<std::string, int> ids = {
      {"DICT_4X4_50", cv::aruco::DICT_4X4_50},   {"DICT_4X4_100", cv::aruco::DICT_4X4_100},
      {"DICT_4X4_250", cv::aruco::DICT_4X4_250}, {"DICT_5X5_50", cv::aruco::DICT_5X5_50},
      {"DICT_5X5_100", cv::aruco::DICT_5X5_100}, {"DICT_5X5_250", cv::aruco::DICT_5X5_250},
      {"DICT_6X6_50", cv::aruco::DICT_6X6_50},   {"DICT_6X6_100", cv::aruco::DICT_6X6_100},
      {"DICT_6X6_250", cv::aruco::DICT_6X6_250}, {"DICT_7X7_250", cv::aruco::DICT_7X7_250},
      {"DICT_ARUCO_ORIGINAL", cv::aruco::DICT_ARUCO_ORIGINAL}};
  auto it = ids.find(name);
  if (it == ids.end()) return fail("unknown ArUco dictionary '" + name + "'");
  return it->second;
}

}  // namespace

Result<BoardDetection> detect_board(const ImageU8& image, const BoardSpec& b) {
  if (image.empty()) return fail("empty image");
  cv::Mat grey = grey_of(image);
  BoardDetection d;
  if (b.kind == BoardSpec::Kind::kChessboard) {
    std::vector<cv::Point2f> corners;
    const cv::Size size(b.cols, b.rows);
    if (!cv::findChessboardCorners(grey, size, corners,
                                   cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK))
      return d;
    // The refinement window must stay inside one square: a fifth of the
    // smallest corner spacing (OpenCV's sample photos: 5 px, as OpenCV's own test).
    double spacing = 1e9;
    for (int i = 0; i < b.rows; ++i)
      for (int j = 0; j + 1 < b.cols; ++j)
        spacing = std::min(spacing, double(cv::norm(corners[size_t(i * b.cols + j + 1)] - corners[size_t(i * b.cols + j)])));
    for (int i = 0; i + 1 < b.rows; ++i)
      for (int j = 0; j < b.cols; ++j)
        spacing = std::min(spacing, double(cv::norm(corners[size_t((i + 1) * b.cols + j)] - corners[size_t(i * b.cols + j)])));
    const int half = std::clamp(static_cast<int>(std::lround(0.2 * spacing)), 2, 11);
    cv::cornerSubPix(grey, corners, cv::Size(half, half), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 0.0001));
    for (int i = 0; i < b.rows; ++i)
      for (int j = 0; j < b.cols; ++j) {
        const auto& c = corners[static_cast<size_t>(i * b.cols + j)];
        d.image_points.emplace_back(c.x, c.y);
        d.board_points.emplace_back(float(j * b.square_m), float(i * b.square_m), 0.f);
        d.ids.push_back(i * b.cols + j);
      }
    d.found = true;
    return d;
  }
  auto dict_id = dictionary_id(b.dictionary);
  if (!dict_id) return std::unexpected(dict_id.error());
  auto dict = cv::aruco::getPredefinedDictionary(*dict_id);
  auto board = cv::aruco::CharucoBoard::create(b.cols, b.rows, static_cast<float>(b.square_m),
                                               static_cast<float>(b.marker_m), dict);
  std::vector<int> marker_ids;
  std::vector<std::vector<cv::Point2f>> marker_corners;
  cv::aruco::detectMarkers(grey, dict, marker_corners, marker_ids);
  if (marker_ids.empty()) return d;
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;
  cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, grey, board, corners, ids);
  if (ids.size() < 4) return d;
  for (size_t k = 0; k < ids.size(); ++k) {
    const auto& p = board->chessboardCorners[static_cast<size_t>(ids[k])];
    d.image_points.emplace_back(corners[k].x, corners[k].y);
    d.board_points.emplace_back(p.x, p.y, p.z);
    d.ids.push_back(ids[k]);
  }
  d.found = true;
  return d;
}

}  // namespace s2r
