// PLY loading: what PCL's reader would abort on or trust blindly is a clear
// error (inputs found by fuzz/fuzz_ply.cpp), and a mesh survives a round trip.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "core/mesh.h"

namespace s2r {
namespace {
namespace fs = std::filesystem;

fs::path write_temp(const std::string& name, const std::string& bytes) {
  const fs::path p = fs::temp_directory_path() / ("s2r_ply_" + std::to_string(getpid()) + "_" + name);
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

std::string error_of(const fs::path& p) {
  auto points = read_ply_points(p);
  auto mesh = read_ply_mesh(p);
  EXPECT_FALSE(points) << p;
  EXPECT_FALSE(mesh) << p;
  fs::remove(p);
  return points ? std::string() : points.error().message;
}

const std::string kAscii = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                           "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                           "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";

TEST(PlyLoad, ValidAsciiTriangle) {
  const auto p = write_temp("ok.ply", kAscii);
  auto mesh = read_ply_mesh(p);
  ASSERT_TRUE(mesh) << mesh.error().message;
  EXPECT_EQ(mesh->vertices.size(), 3u);
  EXPECT_EQ(mesh->faces.size(), 1u);
  auto points = read_ply_points(p);
  ASSERT_TRUE(points) << points.error().message;
  EXPECT_EQ(points->points.size(), 3u);
  fs::remove(p);
}

TEST(PlyLoad, MalformedHeaderLinesAreErrorsNotAborts) {
  // PCL asserts on an obj_info line that is not three words.
  std::string s = kAscii;
  s.insert(s.find("element"), "obj_info is_mesh 0 extra\n");
  EXPECT_NE(error_of(write_temp("objinfo.ply", s)).find("is not a PLY header line"), std::string::npos);
  s = kAscii;
  s.insert(s.find("element"), "obj_info\tnum_cols 4\n");
  EXPECT_NE(error_of(write_temp("tab.ply", s)).find("not printable"), std::string::npos);
  s = kAscii;
  s.replace(s.find("end_header"), 10, "end_headr");
  EXPECT_NE(error_of(write_temp("typo.ply", s)).find("'end_headr' is not a PLY header line"), std::string::npos);
  EXPECT_NE(error_of(write_temp("noend.ply", "ply\nformat ascii 1.0\nelement vertex 3\n")).find("no end_header"),
            std::string::npos);
  EXPECT_NE(error_of(write_temp("notply.ply", "solid cube\n")).find("not a PLY file"), std::string::npos);
  // PCL asserts when CRLF and LF lines are mixed (found by fuzz_ply).
  s = kAscii;
  s.replace(0, 4, "ply\r\n");
  EXPECT_NE(error_of(write_temp("mixed.ply", s)).find("mixes line endings"), std::string::npos);
  // In a CRLF file PCL splits lines at every CR: a CR inside a comment made
  // a line of its own that tripped its obj_info assertion (found by fuzz_ply).
  s = kAscii;
  for (size_t at = s.find('\n'); at != std::string::npos; at = s.find('\n', at + 2)) s.insert(at, "\r");
  s.insert(s.find("element"), "comment one\r obj_info is_mesh 0\r\n");
  EXPECT_NE(error_of(write_temp("cr.ply", s)).find("a carriage return inside the line"), std::string::npos);
  // PCL asserts on vertex lists of varying length (found by fuzz_ply).
  s = kAscii;
  s.insert(s.find("element face"), "property list uchar int extra\n");
  EXPECT_NE(error_of(write_temp("vlist.ply", s)).find("list properties in the vertex element"), std::string::npos);
}

TEST(PlyLoad, ElementCountsBeyondTheFileAreErrorsNotAllocations) {
  // PCL sized its buffer from "element vertex -4": 48 GB (found by fuzz_ply).
  std::string s = kAscii;
  s.replace(s.find("vertex 3"), 8, "vertex -4");
  EXPECT_NE(error_of(write_temp("negative.ply", s)).find("is not a non-negative integer"), std::string::npos);
  s = kAscii;
  s.replace(s.find("vertex 3"), 8, "vertex 3000000000");
  EXPECT_NE(error_of(write_temp("huge.ply", s)).find("more than the file's"), std::string::npos);
}

TEST(PlyLoad, OrganisedCloudSizeMustMatchTheVertices) {
  // PCL sizes its buffer from num_cols x num_rows (read with atoi) and writes
  // every vertex into it: 12 x 4 cells for more vertices tripped its bounds
  // assertion, and "4NSt6locale500" read as 4 (found by fuzz_ply).
  std::string s = kAscii;
  s.insert(s.find("element"), "obj_info num_cols 12\nobj_info num_rows 4\n");
  EXPECT_NE(error_of(write_temp("grid.ply", s)).find("num_cols x num_rows (12 x 4)"), std::string::npos);
  s = kAscii;
  s.insert(s.find("element"), "obj_info num_cols 3\nobj_info num_rows 4NSt6locale500\n");
  EXPECT_NE(error_of(write_temp("atoi.ply", s)).find("num_rows '4NSt6locale500' is not a non-negative integer"),
            std::string::npos);
  // After the vertex element PCL still takes the width: 2 x 1 cells for 3 vertices.
  s = kAscii;
  s.insert(s.find("element face"), "obj_info num_cols 2\n");
  EXPECT_NE(error_of(write_temp("late.ply", s)).find("(2 x 1)"), std::string::npos);
  // A second vertex element writes past the first one's buffer.
  s = kAscii;
  s.insert(s.find("element face"), "element vertex 1\nproperty float x\n");
  EXPECT_NE(error_of(write_temp("twice.ply", s)).find("element 'vertex' is defined twice"), std::string::npos);
  // num_cols x num_rows equal to the vertex count is an organised cloud.
  s = kAscii;
  s.insert(s.find("element"), "obj_info num_cols 3\nobj_info num_rows 1\n");
  const auto p = write_temp("organised.ply", s);
  EXPECT_TRUE(read_ply_points(p));
  fs::remove(p);
}

// A 2 x 2 Stanford range grid over three vertices, one cell empty.
std::string range_grid_ply(const std::string& cells, const std::string& format = "ascii") {
  return "ply\nformat " + format + " 1.0\nobj_info num_cols 2\nobj_info num_rows 2\nelement vertex 3\n"
         "property float x\nproperty float y\nproperty float z\nelement range_grid 4\n"
         "property list uchar int vertex_indices\nend_header\n0 0 1\n1 0 1\n0 1 1\n" + cells;
}

TEST(PlyLoad, RangeGridsAreOrganisedCloudsWithEveryIndexChecked) {
  const auto ok = write_temp("rgrid.ply", range_grid_ply("1 0\n0\n1 1\n1 2\n"));
  auto scan = read_ply_points(ok);
  ASSERT_TRUE(scan) << scan.error().message;
  EXPECT_EQ(scan->grid_width, 2);
  EXPECT_EQ(scan->grid_height, 2);
  EXPECT_EQ(scan->points.size(), 3u);
  EXPECT_EQ(scan->grid_index, (std::vector<int32_t>{0, -1, 1, 2}));
  fs::remove(ok);
  // PCL turns a negative index into a wrapped unsigned offset and reads far
  // outside its buffer; one past the vertices reads cells that hold none.
  EXPECT_NE(error_of(write_temp("neg.ply", range_grid_ply("1 0\n0\n1 -1\n1 2\n"))).find("'-1' is not the index"),
            std::string::npos);
  EXPECT_NE(error_of(write_temp("past.ply", range_grid_ply("1 0\n0\n1 3\n1 2\n"))).find("'3' is not the index"),
            std::string::npos);
  EXPECT_NE(error_of(write_temp("count.ply", range_grid_ply("2 0\n0\n1 1\n1 2\n"))).find("not a count followed"),
            std::string::npos);
  EXPECT_NE(error_of(write_temp("bin.ply", range_grid_ply("", "binary_little_endian"))).find("ASCII files only"),
            std::string::npos);
}

TEST(PlyLoad, VerticesWithoutCoordinatesOrDataAreErrors) {
  // PCL's conversion to points would bind a reference to element 0 of an empty cloud.
  std::string s = kAscii;
  s.replace(s.find("property float z"), 16, "property float w");
  EXPECT_NE(error_of(write_temp("noz.ply", s)).find("no 'z' property"), std::string::npos);
  s = "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  EXPECT_FALSE(error_of(write_temp("empty.ply", s)).empty());
}

TEST(PlyLoad, RoundTrip) {
  Mesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  m.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  const fs::path p = fs::temp_directory_path() / ("s2r_ply_rt_" + std::to_string(getpid()) + ".ply");
  ASSERT_TRUE(write_ply_mesh(p, m));
  auto back = read_ply_mesh(p);
  ASSERT_TRUE(back) << back.error().message;
  // PCL reads back exactly what was written.
  ASSERT_EQ(back->vertices.size(), m.vertices.size());
  ASSERT_EQ(back->faces.size(), m.faces.size());
  for (size_t i = 0; i < m.vertices.size(); ++i) EXPECT_EQ(back->vertices[i], m.vertices[i]);
  for (size_t i = 0; i < m.faces.size(); ++i) EXPECT_EQ(back->faces[i], m.faces[i]);
  // A face naming no vertex is refused, and the file written before stays.
  Mesh bad = m;
  bad.faces.push_back({0, 1, 4});
  EXPECT_FALSE(write_ply_mesh(p, bad));
  auto kept = read_ply_mesh(p);
  ASSERT_TRUE(kept) << kept.error().message;
  EXPECT_EQ(kept->faces.size(), m.faces.size());
  // No faces: a point set with an empty face element.
  Mesh points;
  points.vertices = {{0.5f, -1.25f, 3}};
  ASSERT_TRUE(write_ply_mesh(p, points));
  auto pts = read_ply_mesh(p);
  ASSERT_TRUE(pts) << pts.error().message;
  EXPECT_EQ(pts->vertices.size(), 1u);
  EXPECT_EQ(pts->vertices[0], points.vertices[0]);
  EXPECT_TRUE(pts->faces.empty());
  fs::remove(p);
}

}  // namespace
}  // namespace s2r
