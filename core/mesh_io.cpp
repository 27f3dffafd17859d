// The only translation unit of core/ that includes PCL.
#include <pcl/PolygonMesh.h>
#include <pcl/conversions.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <cctype>
#include <cmath>
#include <fstream>
#include <string>
#include <vector>

#include "core/atomic_file.h"
#include "core/mesh.h"

namespace s2r {
namespace fs = std::filesystem;

void Mesh::compute_vertex_normals() {
  normals.assign(vertices.size(), Eigen::Vector3f::Zero());
  for (const auto& f : faces) {
    const Eigen::Vector3f n = (vertices[f[1]] - vertices[f[0]]).cross(vertices[f[2]] - vertices[f[0]]);
    for (int k = 0; k < 3; ++k) normals[f[k]] += n;
  }
  for (auto& n : normals) {
    float len = n.norm();
    n = len > 0 ? Eigen::Vector3f(n / len) : Eigen::Vector3f(0, 0, 1);
  }
}

Eigen::AlignedBox3f Mesh::bounds() const {
  Eigen::AlignedBox3f b;
  for (const auto& v : vertices) b.extend(v);
  return b;
}

void Mesh::transform(const Eigen::Isometry3d& t) {
  const Eigen::Isometry3f tf = t.cast<float>();
  for (auto& v : vertices) v = tf * v;
  for (auto& n : normals) n = (tf.linear() * n).normalized();
}

namespace {
Status check_exists(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return fail("'" + path.string() + "': PLY file not found");
  if (fs::file_size(path, ec) == 0) return fail("'" + path.string() + "': PLY file is empty");
  return {};
}

struct PlyProperty {
  std::string name;
  bool list = false;
};
struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> properties;
};

bool is_decimal(const std::string& s, size_t max_digits) {
  return !s.empty() && s.size() <= max_digits &&
         std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

// A Stanford range grid (element range_grid, one list of vertex indices per
// grid cell) is where PCL reorders the vertices into an organised cloud. It
// trusts every index: a negative one wraps its unsigned offset and reads far
// outside the buffer. Only the ASCII form is read (the one the Stanford scans
// use); every index must name a vertex.
Status check_range_grid(const fs::path& path, size_t body_offset, bool crlf, const std::vector<PlyElement>& elements,
                        uint64_t vertices) {
  const std::string at = "'" + path.string() + "': ";
  std::ifstream in(path, std::ios::binary);
  in.seekg(static_cast<std::streamoff>(body_offset));
  std::string line;
  uint64_t line_no = 0;
  for (const auto& e : elements) {
    for (uint64_t i = 0; i < e.count; ++i) {
      if (!std::getline(in, line)) return {};  // short body: PCL's own parse error
      ++line_no;
      if (e.name != "range_grid") continue;
      // PCL splits a CRLF file's lines at CR (see check_ply_header): one CR, at the end.
      if (crlf && (line.empty() || line.back() != '\r' || line.find('\r') + 1 != line.size()))
        return fail(at + "PLY body line " + std::to_string(line_no) + " does not end in CRLF, as the header's lines do");
      std::vector<std::string> words;
      for (size_t p = 0; p < line.size();) {
        while (p < line.size() && std::isspace(static_cast<unsigned char>(line[p]))) ++p;
        size_t q = p;
        while (q < line.size() && !std::isspace(static_cast<unsigned char>(line[q]))) ++q;
        if (q > p) words.push_back(line.substr(p, q - p));
        p = q;
      }
      const std::string where = at + "PLY range_grid cell " + std::to_string(i) + " (body line " +
                                std::to_string(line_no) + "): ";
      if (words.empty() || !is_decimal(words[0], 3) || std::stoul(words[0]) != words.size() - 1)
        return fail(where + "not a count followed by that many vertex indices");
      for (size_t k = 1; k < words.size(); ++k)
        if (!is_decimal(words[k], 18) || std::stoull(words[k]) >= vertices)
          return fail(where + "'" + words[k].substr(0, 20) + "' is not the index of one of the " +
                      std::to_string(vertices) + " vertices");
    }
  }
  return {};
}

// PCL's PLY reader asserts (aborts) on some malformed header lines, e.g. an
// obj_info line without exactly three words, and trusts what it derives from
// the header. The header is checked against the PLY grammar first: printable
// words separated by single spaces, the keywords PCL knows with their word
// counts, "end_header" within 64 KiB; then what PCL sizes from it: element
// counts, the organised cloud's num_cols x num_rows, the range grid.
Status check_ply_header(const fs::path& path) {
  const std::string at = "'" + path.string() + "': ";
  std::error_code ec;
  const uint64_t file_bytes = fs::file_size(path, ec);
  std::ifstream in(path, std::ios::binary);
  std::string head(64 * 1024, '\0');
  in.read(head.data(), static_cast<std::streamsize>(head.size()));
  head.resize(static_cast<size_t>(in.gcount()));
  size_t pos = 0;
  bool crlf = false;
  std::string format;
  std::vector<PlyElement> elements;  // property lines belong to the last one
  // The organised cloud's size as PCL sets it: obj_info num_cols / num_rows,
  // else the vertex count by one when the vertex element is defined.
  uint64_t width = 0, height = 0;
  for (int n = 1;; ++n) {
    const size_t nl = head.find('\n', pos);
    if (nl == std::string::npos) return fail(at + "PLY header has no end_header line in its first 64 KiB");
    std::string line = head.substr(pos, nl - pos);
    pos = nl + 1;
    // PCL's parser takes the first line's ending for every line; mixed
    // endings run its lines together (and trip an assertion in it).
    const bool cr = !line.empty() && line.back() == '\r';
    if (n == 1) crlf = cr;
    if (cr != crlf) return fail(at + "PLY header line " + std::to_string(n) + " mixes line endings (CRLF and LF)");
    if (cr) line.pop_back();
    const std::string where = at + "PLY header line " + std::to_string(n) + ": ";
    // In a CRLF file PCL ends a line at every CR and drops the character
    // after it: a CR inside a comment starts a line of its own there (fuzz:
    // one beginning with a space tripped the assertion in its obj_info parser).
    if (crlf && line.find('\r') != std::string::npos) return fail(where + "a carriage return inside the line");
    if (n == 1) {
      if (line != "ply") return fail(at + "not a PLY file (first line is not 'ply')");
      continue;
    }
    if (line == "end_header") break;
    std::vector<std::string> words;
    for (size_t i = 0; i <= line.size();) {
      const size_t sp = std::min(line.find(' ', i), line.size());
      words.push_back(line.substr(i, sp - i));
      i = sp + 1;
    }
    const std::string& key = words[0];
    if (key == "comment") continue;
    for (char c : line)
      if (c < 0x20 || c >= 0x7f) return fail(where + "not printable text");
    for (const auto& w : words)
      if (w.empty()) return fail(where + "words must be separated by single spaces");
    const size_t k = words.size();
    const bool ok = (key == "format" && k == 3) || (key == "obj_info" && k == 3) || (key == "element" && k == 3) ||
                    (key == "property" && (k == 3 || (k == 5 && words[1] == "list")));
    if (!ok) return fail(where + "'" + line.substr(0, 60) + "' is not a PLY header line");
    if (key == "format") format = words[1];
    if (key == "obj_info" && (words[1] == "num_cols" || words[1] == "num_rows")) {
      // PCL reads these with atoi: "4NSt6locale500" is 4, "-1" a 4-billion-wide cloud.
      if (!is_decimal(words[2], 9))
        return fail(where + words[1] + " '" + words[2].substr(0, 20) + "' is not a non-negative integer");
      (words[1] == "num_cols" ? width : height) = std::stoull(words[2]);
    }
    if (key == "property") {
      if (elements.empty()) return fail(where + "a property before any element");
      const PlyProperty p{words[k - 1], k == 5};
      if (p.list && elements.back().name == "vertex")
        // PCL asserts on a vertex list whose length changes from vertex to vertex.
        return fail(where + "list properties in the vertex element are not supported");
      elements.back().properties.push_back(p);
    }
    if (key == "element") {
      // PCL reads the count as a signed number and sizes its buffer from it
      // (fuzz: "element vertex -4" asked for 48 GB). A count is decimal
      // digits, and each element takes at least a byte of the file.
      const std::string& count = words[2];
      if (!is_decimal(count, 18))
        return fail(where + "element count '" + count.substr(0, 20) + "' is not a non-negative integer");
      if (!ec && std::stoull(count) > file_bytes)
        return fail(where + "element count " + count + " is more than the file's " + std::to_string(file_bytes) +
                    " bytes can hold");
      for (const auto& e : elements)
        // A second vertex element is written past the first one's buffer.
        if (e.name == words[1]) return fail(where + "element '" + words[1] + "' is defined twice");
      elements.push_back({words[1], std::stoull(count), {}});
      if (words[1] == "vertex" && (width == 0 || height == 0)) {
        width = elements.back().count;
        height = 1;
      }
    }
  }
  const PlyElement *vertex = nullptr, *grid = nullptr;
  for (const auto& e : elements) {
    if (e.name == "vertex") vertex = &e;
    if (e.name == "range_grid") grid = &e;
  }
  const uint64_t vertices = vertex ? vertex->count : 0;
  // PCL sizes its point buffer to width x height and writes the vertices into
  // it in file order (fuzz: num_cols 12 x num_rows 4 with more vertices
  // tripped its bounds assertion). An organised cloud has a vertex per cell,
  // or a range grid that says which vertex each cell holds.
  if (vertex && width * height != vertices && !(grid && width * height == grid->count))
    return fail(at + "PLY num_cols x num_rows (" + std::to_string(width) + " x " + std::to_string(height) +
                ") is neither the vertex count (" + std::to_string(vertices) + ") nor a range grid's cell count");
  if (grid) {
    const bool index_list = grid->properties.size() == 1 && grid->properties[0].list &&
                            (grid->properties[0].name == "vertex_indices" || grid->properties[0].name == "vertex_index");
    if (!index_list)
      return fail(at + "PLY range_grid must hold one property, the list vertex_indices");
    if (format != "ascii") return fail(at + "PLY range_grid is read in ASCII files only (this one is " + format + ")");
    return check_range_grid(path, pos, crlf, elements, vertices);
  }
  return {};
}

// PCL's conversion to typed points trusts the blob the reader made of the
// header; check it first: vertices present, x/y/z present, every property
// inside the vertex record, and as many bytes as the header promises.
Status check_vertices(const pcl::PCLPointCloud2& b, const fs::path& path) {
  const std::string at = "'" + path.string() + "': ";
  const uint64_t n = uint64_t(b.width) * b.height;
  if (n == 0) return fail(at + "PLY has no vertices");
  for (const char* axis : {"x", "y", "z"})
    if (std::none_of(b.fields.begin(), b.fields.end(), [&](const pcl::PCLPointField& f) { return f.name == axis; }))
      return fail(at + "PLY vertices have no '" + axis + "' property");
  for (const auto& f : b.fields) {
    const uint64_t size = uint64_t(pcl::getFieldSize(f.datatype)) * std::max<uint32_t>(f.count, 1);
    if (size == 0 || f.offset + size > b.point_step)
      return fail(at + "PLY property '" + f.name + "' lies outside the vertex record");
  }
  if (b.row_step != uint64_t(b.width) * b.point_step || b.data.size() < n * b.point_step)
    return fail(at + "PLY vertex data is shorter than its header says (truncated?)");
  return {};
}
}  // namespace

Result<Mesh> read_ply_mesh(const fs::path& path) {
  if (auto st = check_exists(path); !st) return std::unexpected(st.error());
  if (auto st = check_ply_header(path); !st) return std::unexpected(st.error());
  pcl::PolygonMesh pm;
  pcl::PLYReader reader;
  if (reader.read(path.string(), pm) < 0)
    return fail("'" + path.string() + "': cannot parse PLY (truncated or corrupt?)");
  if (auto st = check_vertices(pm.cloud, path); !st) return std::unexpected(st.error());
  pcl::PointCloud<pcl::PointXYZ> cloud;
  pcl::fromPCLPointCloud2(pm.cloud, cloud);
  Mesh m;
  m.vertices.reserve(cloud.size());
  for (const auto& p : cloud.points) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      return fail("'" + path.string() + "': vertex " + std::to_string(m.vertices.size()) +
                  " is not finite");
    m.vertices.emplace_back(p.x, p.y, p.z);
  }
  const int n = static_cast<int>(m.vertices.size());
  for (size_t i = 0; i < pm.polygons.size(); ++i) {
    const auto& idx = pm.polygons[i].vertices;
    if (idx.size() < 3) continue;
    for (size_t k = 0; k < idx.size(); ++k)
      if (static_cast<int>(idx[k]) < 0 || static_cast<int>(idx[k]) >= n)
        return fail("'" + path.string() + "': face " + std::to_string(i) +
                    " refers to vertex " + std::to_string(idx[k]) + " of " + std::to_string(n));
    for (size_t k = 1; k + 1 < idx.size(); ++k)  // fan-triangulate polygons
      m.faces.emplace_back(idx[0], idx[k], idx[k + 1]);
  }
  if (m.vertices.empty()) return fail("'" + path.string() + "': PLY has no vertices");
  bool has_color = false;
  for (const auto& field : pm.cloud.fields) has_color |= field.name == "rgb" || field.name == "rgba";
  if (has_color) {
    pcl::PointCloud<pcl::PointXYZRGB> rgb;
    pcl::fromPCLPointCloud2(pm.cloud, rgb);
    m.colors.reserve(rgb.size());
    for (const auto& p : rgb.points) m.colors.emplace_back(p.r / 255.0f, p.g / 255.0f, p.b / 255.0f);
  }
  return m;
}

Result<PointScan> read_ply_points(const fs::path& path) {
  if (auto st = check_exists(path); !st) return std::unexpected(st.error());
  if (auto st = check_ply_header(path); !st) return std::unexpected(st.error());
  pcl::PCLPointCloud2 blob;
  pcl::PLYReader reader;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int version = 0;
  if (reader.read(path.string(), blob, origin, orientation, version) < 0)
    return fail("'" + path.string() + "': cannot parse PLY (truncated or corrupt?)");
  if (auto st = check_vertices(blob, path); !st) return std::unexpected(st.error());
  pcl::PointCloud<pcl::PointXYZ> cloud;
  pcl::fromPCLPointCloud2(blob, cloud);
  PointScan scan;
  const bool organized = cloud.height > 1;
  if (organized) {
    scan.grid_width = static_cast<int>(cloud.width);
    scan.grid_height = static_cast<int>(cloud.height);
    scan.grid_index.assign(cloud.size(), -1);
  }
  for (size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud.points[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
    if (organized) scan.grid_index[i] = static_cast<int32_t>(scan.points.size());
    scan.points.emplace_back(p.x, p.y, p.z);
  }
  if (scan.points.empty()) return fail("'" + path.string() + "': PLY has no finite points");
  return scan;
}

// Binary PLY in the machine's byte order, written from one buffer (PCL's
// writer makes a vector per face and writes field by field: 18 ms for the
// rig bunny's 63k-triangle patch mesh). read_ply_mesh (PCL) reads it back.
Status write_ply_mesh(const fs::path& path, const Mesh& mesh) {
  for (const auto& f : mesh.faces)
    for (int k = 0; k < 3; ++k)
      if (f[k] < 0 || size_t(f[k]) >= mesh.vertices.size())
        return fail("'" + path.string() + "': a face refers to vertex " + std::to_string(f[k]) + " of " +
                    std::to_string(mesh.vertices.size()));
  const std::string header = std::string("ply\nformat ") +
                             (std::endian::native == std::endian::little ? "binary_little_endian" : "binary_big_endian") +
                             " 1.0\nelement vertex " + std::to_string(mesh.vertices.size()) +
                             "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                             std::to_string(mesh.faces.size()) + "\nproperty list uchar int vertex_indices\nend_header\n";
  constexpr size_t kFaceBytes = 1 + 3 * sizeof(int32_t);
  std::string buf(header.size() + mesh.vertices.size() * 3 * sizeof(float) + mesh.faces.size() * kFaceBytes, '\0');
  char* out = buf.data();
  std::memcpy(out, header.data(), header.size());
  out += header.size();
  for (const auto& v : mesh.vertices) {
    const float xyz[3] = {v.x(), v.y(), v.z()};
    std::memcpy(out, xyz, sizeof xyz);
    out += sizeof xyz;
  }
  for (const auto& f : mesh.faces) {
    const int32_t idx[3] = {f[0], f[1], f[2]};
    *out++ = 3;
    std::memcpy(out, idx, sizeof idx);
    out += sizeof idx;
  }
  return write_file_atomic(path, buf);
}

Status write_ply_points(const fs::path& path, const PointScan& scan) {
  return write_via_temp(path, [&](const fs::path& tmp) -> Status {
    pcl::PointCloud<pcl::PointXYZ> cloud;
    for (const auto& v : scan.points) cloud.emplace_back(v.x(), v.y(), v.z());
    if (pcl::io::savePLYFileBinary(tmp.string(), cloud) < 0) return fail("PCL could not write PLY");
    return {};
  });
}

}  // namespace s2r
