// The only translation unit of core/ that includes PCL: PLY files are parsed
// by PCL's PLY parser (libpcl_io_ply, the parser PCL's PLYReader is built on,
// without the rest of libpcl_io and the VTK libraries it loads).
#include <pcl/io/ply/ply_parser.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <functional>
#include <limits>
#include <tuple>
#include <type_traits>
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

// What a PLY file holds for us, read by PCL's parser with the semantics of
// PCL's PLYReader: float x/y/z (any other type of them is an error here;
// PLYReader's conversion left such points at 0), red/green/blue (or
// diffuse_*) bytes, faces, and the organised grid of a range scan (obj_info
// num_cols x num_rows; a range_grid element names each cell's vertex).
struct PlyContents {
  uint64_t width = 0, height = 0;  // the organised size; height 1 for a plain cloud
  uint64_t vertices = 0;           // vertex records read
  std::vector<float> xyz;          // 3 per vertex record
  std::vector<uint8_t> rgb;        // 3 per vertex record, when has_rgb
  bool has_x = false, has_y = false, has_z = false, has_rgb = false;
  std::vector<std::vector<int64_t>> faces;
  std::vector<int64_t> grid;       // per range_grid cell: its first vertex index, -1 none
  std::string bad;                 // a property we refuse, named
};

Result<PlyContents> parse_ply(const fs::path& path, bool want_faces) {
  namespace ply = pcl::io::ply;
  PlyContents c;
  std::string parser_error;
  ply::ply_parser parser;
  parser.info_callback([](std::size_t, const std::string&) {});
  parser.warning_callback([](std::size_t, const std::string&) {});
  parser.error_callback([&](std::size_t line, const std::string& message) {
    if (parser_error.empty()) parser_error = "line " + std::to_string(line) + ": " + message;
  });
  parser.obj_info_callback([&](const std::string& line) {
    // "obj_info num_cols 512": check_ply_header made them decimal.
    std::vector<std::string> w;
    for (size_t i = 0; i < line.size();) {
      const size_t sp = std::min(line.find(' ', i), line.size());
      if (sp > i) w.push_back(line.substr(i, sp - i));
      i = sp + 1;
    }
    if (w.size() >= 3 && (w[1] == "num_cols" || w[1] == "num_rows"))
      (w[1] == "num_cols" ? c.width : c.height) = std::strtoull(w[2].c_str(), nullptr, 10);
  });
  uint64_t record = 0;  // the vertex record being read
  parser.element_definition_callback([&](const std::string& name, std::size_t count) -> ply::ply_parser::element_callbacks_type {
    if (name == "vertex") {
      if (c.width == 0 || c.height == 0) c.width = count, c.height = 1;
      c.xyz.reserve(3 * count);
      return {[&] {
                record = c.vertices;
                c.xyz.insert(c.xyz.end(), 3, 0.0f);
                if (c.has_rgb) c.rgb.insert(c.rgb.end(), 3, uint8_t(0));
              },
              [&] { ++c.vertices; }};
    }
    if (name == "face" && want_faces) {
      c.faces.reserve(count);
      return {std::function<void()>([&] { c.faces.emplace_back(); }), std::function<void()>{}};
    }
    if (name == "range_grid") {
      c.grid.reserve(count);
      return {std::function<void()>([&] { c.grid.push_back(-1); }), std::function<void()>{}};
    }
    return {};
  });
  // Scalars: x, y, z as float; colour bytes; anything else is read and dropped.
  ply::ply_parser::scalar_property_definition_callbacks_type scalars;
  auto axis_of = [](const std::string& p) { return p == "x" ? 0 : p == "y" ? 1 : p == "z" ? 2 : -1; };
  auto colour_of = [](const std::string& p) {
    if (p == "red" || p == "diffuse_red") return 0;
    if (p == "green" || p == "diffuse_green") return 1;
    if (p == "blue" || p == "diffuse_blue") return 2;
    return -1;
  };
  ply::ply_parser::at<ply::float32>(scalars) = [&](const std::string& element, const std::string& property) {
    const int k = axis_of(property);
    if (element != "vertex" || k < 0) return std::function<void(ply::float32)>{};
    (k == 0 ? c.has_x : k == 1 ? c.has_y : c.has_z) = true;
    return std::function<void(ply::float32)>([&, k](ply::float32 v) { c.xyz[3 * record + size_t(k)] = v; });
  };
  ply::ply_parser::at<ply::uint8>(scalars) = [&](const std::string& element, const std::string& property) {
    const int k = colour_of(property);
    if (element != "vertex" || k < 0) return std::function<void(ply::uint8)>{};
    c.has_rgb = true;
    // has_rgb is set by the header, before the first record makes its slots.
    return std::function<void(ply::uint8)>([&, k](ply::uint8 v) { c.rgb[3 * record + size_t(k)] = v; });
  };
  auto refuse_axes = [&]<class T>(const std::string& element, const std::string& property) {
    if (element == "vertex" && axis_of(property) >= 0 && c.bad.empty())
      c.bad = "vertex property '" + property + "' is not a float (only float x, y, z are read)";
    return std::function<void(T)>{};
  };
  [&]<class... T>(std::type_identity<T>...) {
    ((ply::ply_parser::at<T>(scalars) = [&](const std::string& e, const std::string& p) {
       return refuse_axes.template operator()<T>(e, p);
     }), ...);
  }(std::type_identity<ply::int8>{}, std::type_identity<ply::int16>{}, std::type_identity<ply::uint16>{},
    std::type_identity<ply::int32>{}, std::type_identity<ply::uint32>{}, std::type_identity<ply::float64>{});
  parser.scalar_property_definition_callbacks(scalars);
  // Lists: a face's vertex indices, a range grid cell's vertices.
  ply::ply_parser::list_property_definition_callbacks_type lists;
  auto index_list = [&]<class S, class T>(const std::string& element, const std::string& property) {
    using Callbacks = std::tuple<std::function<void(S)>, std::function<void(T)>, std::function<void()>>;
    if (property != "vertex_indices" && property != "vertex_index") return Callbacks{};
    if (element == "face" && want_faces)
      return Callbacks(std::function<void(S)>{}, std::function<void(T)>([&](T i) { c.faces.back().push_back(int64_t(i)); }),
                       std::function<void()>{});
    if (element == "range_grid")
      return Callbacks(std::function<void(S)>{}, std::function<void(T)>([&](T i) {
                         if (c.grid.back() < 0) c.grid.back() = int64_t(i);
                       }),
                       std::function<void()>{});
    return Callbacks{};
  };
  // Every size type with signed and unsigned 32-bit indices.
  [&]<class... S>(std::type_identity<S>...) {
    ((ply::ply_parser::at<S, ply::int32>(lists) = [&](const std::string& e, const std::string& p) {
       return index_list.template operator()<S, ply::int32>(e, p);
     }), ...);
    ((ply::ply_parser::at<S, ply::uint32>(lists) = [&](const std::string& e, const std::string& p) {
       return index_list.template operator()<S, ply::uint32>(e, p);
     }), ...);
  }(std::type_identity<ply::uint8>{}, std::type_identity<ply::uint16>{}, std::type_identity<ply::uint32>{});
  parser.list_property_definition_callbacks(lists);

  const std::string at = "'" + path.string() + "': ";
  if (!parser.parse(path.string()))
    return fail(ErrorCode::format, at + "cannot parse PLY (truncated or corrupt?)" +
                                       (parser_error.empty() ? "" : ": " + parser_error));
  if (!c.bad.empty()) return fail(ErrorCode::format, at + "PLY " + c.bad);
  if (c.vertices == 0 || c.width * c.height == 0) return fail(ErrorCode::format, at + "PLY has no vertices");
  for (const auto& [has, axis] : {std::pair{c.has_x, "x"}, {c.has_y, "y"}, {c.has_z, "z"}})
    if (!has) return fail(ErrorCode::format, at + "PLY vertices have no '" + axis + "' property");
  c.xyz.resize(3 * c.vertices);
  if (c.has_rgb) c.rgb.resize(3 * c.vertices, 0);
  // A range grid other than one cell per vertex puts vertex grid[r] in cell
  // r, and an empty cell is not a number (PLYReader's reorganisation).
  if (!c.grid.empty() && c.grid.size() != c.vertices) {
    std::vector<float> xyz(3 * c.grid.size(), std::numeric_limits<float>::quiet_NaN());
    std::vector<uint8_t> rgb(c.has_rgb ? 3 * c.grid.size() : 0, 0);
    for (size_t r = 0; r < c.grid.size(); ++r) {
      const int64_t v = c.grid[r];
      if (v < 0) continue;
      if (uint64_t(v) >= c.vertices)
        return fail(ErrorCode::format, at + "PLY range_grid cell " + std::to_string(r) + " names vertex " +
                                           std::to_string(v) + " of " + std::to_string(c.vertices));
      std::copy_n(&c.xyz[3 * size_t(v)], 3, &xyz[3 * r]);
      if (c.has_rgb) std::copy_n(&c.rgb[3 * size_t(v)], 3, &rgb[3 * r]);
    }
    c.xyz.swap(xyz);
    c.rgb.swap(rgb);
    c.vertices = c.grid.size();
  }
  // The organised size holds exactly the records read (check_ply_header
  // made num_cols x num_rows the vertex or the grid's cell count).
  if (c.width * c.height != c.vertices)
    return fail(ErrorCode::format, at + "PLY vertex data is shorter than its header says (truncated?)");
  return c;
}
}  // namespace

Result<Mesh> read_ply_mesh(const fs::path& path) {
  if (auto st = check_exists(path); !st) return std::unexpected(st.error());
  if (auto st = check_ply_header(path); !st) return std::unexpected(st.error());
  auto c = parse_ply(path, true);
  if (!c) return std::unexpected(c.error());
  Mesh m;
  m.vertices.reserve(c->vertices);
  for (size_t i = 0; i < c->vertices; ++i) {
    const float x = c->xyz[3 * i], y = c->xyz[3 * i + 1], z = c->xyz[3 * i + 2];
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z))
      return fail(ErrorCode::format, "'" + path.string() + "': vertex " + std::to_string(i) + " is not finite");
    m.vertices.emplace_back(x, y, z);
  }
  const int64_t n = int64_t(m.vertices.size());
  for (size_t i = 0; i < c->faces.size(); ++i) {
    const auto& idx = c->faces[i];
    if (idx.size() < 3) continue;
    for (const int64_t k : idx)
      // PLYReader kept indices as int32: an unsigned one past 2^31 was negative.
      if (int32_t(k) < 0 || int32_t(k) >= n)
        return fail(ErrorCode::format, "'" + path.string() + "': face " + std::to_string(i) + " refers to vertex " +
                                           std::to_string(uint32_t(k)) + " of " + std::to_string(n));
    for (size_t k = 1; k + 1 < idx.size(); ++k)  // fan-triangulate polygons
      m.faces.emplace_back(int(idx[0]), int(idx[k]), int(idx[k + 1]));
  }
  if (c->has_rgb) {
    m.colors.reserve(c->vertices);
    for (size_t i = 0; i < c->vertices; ++i)
      m.colors.emplace_back(c->rgb[3 * i] / 255.0f, c->rgb[3 * i + 1] / 255.0f, c->rgb[3 * i + 2] / 255.0f);
  }
  return m;
}

Result<PointScan> read_ply_points(const fs::path& path) {
  if (auto st = check_exists(path); !st) return std::unexpected(st.error());
  if (auto st = check_ply_header(path); !st) return std::unexpected(st.error());
  auto c = parse_ply(path, false);
  if (!c) return std::unexpected(c.error());
  PointScan scan;
  const bool organized = c->height > 1;
  if (organized) {
    scan.grid_width = static_cast<int>(c->width);
    scan.grid_height = static_cast<int>(c->height);
    scan.grid_index.assign(c->vertices, -1);
  }
  for (size_t i = 0; i < c->vertices; ++i) {
    const float x = c->xyz[3 * i], y = c->xyz[3 * i + 1], z = c->xyz[3 * i + 2];
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
    if (organized) scan.grid_index[i] = static_cast<int32_t>(scan.points.size());
    scan.points.emplace_back(x, y, z);
  }
  if (scan.points.empty()) return fail(ErrorCode::format, "'" + path.string() + "': PLY has no finite points");
  return scan;
}

// Binary PLY in the machine's byte order, written from one buffer (PCL's
// writer makes a vector per face and writes field by field: 18 ms for the
// rig bunny's 63k-triangle patch mesh). read_ply_mesh reads it back.
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

// Binary PLY of float x, y, z in the machine's byte order, from one buffer.
Status write_ply_points(const fs::path& path, const PointScan& scan) {
  const std::string header = std::string("ply\nformat ") +
                             (std::endian::native == std::endian::little ? "binary_little_endian" : "binary_big_endian") +
                             " 1.0\nelement vertex " + std::to_string(scan.points.size()) +
                             "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  std::string buf(header.size() + scan.points.size() * 3 * sizeof(float), '\0');
  std::memcpy(buf.data(), header.data(), header.size());
  char* out = buf.data() + header.size();
  for (const auto& v : scan.points) {
    const float xyz[3] = {v.x(), v.y(), v.z()};
    std::memcpy(out, xyz, sizeof xyz);
    out += sizeof xyz;
  }
  return write_file_atomic(path, buf);
}

}  // namespace s2r
