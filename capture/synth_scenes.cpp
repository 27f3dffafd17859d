#include "capture/synth_scenes.h"

#include <array>
#include <cmath>
#include <numbers>
#include <random>

namespace s2r::synth {
namespace fs = std::filesystem;
using Eigen::Vector3d;
using Eigen::Vector3f;

namespace {

// Camera at `eye` looking at `target`, table z up; OpenCV axes (x right, y down).
Eigen::Isometry3d look_at(const Vector3d& eye, const Vector3d& target, double roll_deg) {
  const Vector3d z = (target - eye).normalized();
  const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();
  const Vector3d y = z.cross(x);
  Eigen::Matrix3d r;
  r.col(0) = x;
  r.col(1) = y;
  r.col(2) = z;
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = r * Eigen::AngleAxisd(roll_deg * std::numbers::pi / 180, Vector3d::UnitZ());
  t.translation() = eye;
  return t;
}

Mesh uv_sphere(const Vector3f& centre, float radius, int rings, int segments) {
  Mesh m;
  for (int i = 0; i <= rings; ++i) {
    const float th = std::numbers::pi_v<float> * float(i) / float(rings);
    for (int j = 0; j < segments; ++j) {
      const float ph = 2 * std::numbers::pi_v<float> * float(j) / float(segments);
      m.vertices.push_back(centre + radius * Vector3f(std::sin(th) * std::cos(ph),
                                                      std::sin(th) * std::sin(ph), std::cos(th)));
    }
  }
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const int a = i * segments + j, b = i * segments + (j + 1) % segments;
      const int c = a + segments, d = b + segments;
      if (i > 0) m.faces.emplace_back(a, c, b);
      if (i < rings - 1) m.faces.emplace_back(b, c, d);
    }
  return m;
}

// Axis-aligned box; `inward` flips the faces (a room seen from inside).
Mesh box(const Vector3f& lo, const Vector3f& hi, bool inward) {
  Mesh m;
  for (int i = 0; i < 8; ++i)
    m.vertices.emplace_back(i & 1 ? hi.x() : lo.x(), i & 2 ? hi.y() : lo.y(), i & 4 ? hi.z() : lo.z());
  const int q[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& f : q) {
    if (inward) {
      m.faces.emplace_back(f[0], f[2], f[1]);
      m.faces.emplace_back(f[0], f[3], f[2]);
    } else {
      m.faces.emplace_back(f[0], f[1], f[2]);
      m.faces.emplace_back(f[0], f[2], f[3]);
    }
  }
  // Flat shading for boxes: split vertices per face.
  Mesh flat;
  for (const auto& f : m.faces) {
    const int base = static_cast<int>(flat.vertices.size());
    for (int k = 0; k < 3; ++k) flat.vertices.push_back(m.vertices[f[k]]);
    flat.faces.emplace_back(base, base + 1, base + 2);
  }
  return flat;
}

Result<Scene> bunny(const fs::path& data_dir) {
  const fs::path ply = data_dir / "stanford_bunny" / "bun_zipper.ply";
  auto mesh = read_ply_mesh(ply);
  if (!mesh)
    return fail("scene 'bunny' needs " + ply.string() + " (set S2R_DATA, or choose the blob scene): " +
                mesh.error().message);
  // The scan is y-up; the table is z-up. Stand it on the table, centred on the axis.
  Eigen::Isometry3d up = Eigen::Isometry3d::Identity();
  up.linear() = Eigen::AngleAxisd(std::numbers::pi / 2, Vector3d::UnitX()).toRotationMatrix();
  mesh->transform(up);
  const auto b = mesh->bounds();
  Eigen::Isometry3d centre = Eigen::Isometry3d::Identity();
  centre.translation() = Vector3d(-b.center().x(), -b.center().y(), -b.min().z());
  mesh->transform(centre);
  mesh->compute_vertex_normals();
  Scene s;
  s.name = "bunny";
  s.surfaces.push_back({std::move(*mesh), Texture::kPatches});
  s.table_from_camera = look_at({0, -0.32, 0.19}, {0, 0, 0.075}, 1.5);
  s.light_dir_lab = Vector3d(-0.3, -0.8, 0.6).normalized();
  return s;
}

Scene blob() {
  Mesh m = uv_sphere({0, 0, 0.08f}, 0.06f, 48, 96);
  for (auto& v : m.vertices) {  // a lumpy closed object
    Vector3f d = v - Vector3f(0, 0, 0.08f);
    const float r = 1 + 0.18f * std::sin(5 * d.x() / 0.06f) * std::cos(4 * d.y() / 0.06f) +
                    0.1f * std::sin(7 * d.z() / 0.06f);
    v = Vector3f(0, 0, 0.08f) + d * r;
  }
  m.compute_vertex_normals();
  Scene s;
  s.name = "blob";
  s.surfaces.push_back({std::move(m), Texture::kPatches});
  s.table_from_camera = look_at({0, -0.45, 0.26}, {0, 0, 0.08}, 1.5);
  s.light_dir_lab = Vector3d(-0.3, -0.8, 0.6).normalized();
  return s;
}

// A vase: a closed surface of revolution about the table axis (z), so its
// depth is the same at every table angle: registration from geometry alone
// cannot tell the angle (the symmetric stiff case). Textured, so colour can.
Scene vase() {
  constexpr int kRings = 96, kSegments = 256;
  constexpr float kHeight = 0.16f;
  auto radius = [](float z) {  // metres; a belly, a neck and a lip
    const float u = z / kHeight;
    return 0.035f + 0.02f * std::sin(std::numbers::pi_v<float> * u * 1.2f) - 0.012f * u * u + 0.004f * u * u * u * u;
  };
  Mesh m;
  m.vertices.emplace_back(0.f, 0.f, 0.f);  // bottom centre
  for (int i = 0; i <= kRings; ++i) {
    const float z = kHeight * float(i) / float(kRings);
    for (int j = 0; j < kSegments; ++j) {
      const float ph = 2 * std::numbers::pi_v<float> * float(j) / float(kSegments);
      m.vertices.emplace_back(radius(z) * std::cos(ph), radius(z) * std::sin(ph), z);
    }
  }
  m.vertices.emplace_back(0.f, 0.f, kHeight);  // top centre
  const int top = static_cast<int>(m.vertices.size()) - 1;
  auto at = [](int i, int j) { return 1 + i * kSegments + (j % kSegments); };
  for (int j = 0; j < kSegments; ++j) {
    m.faces.emplace_back(0, at(0, j + 1), at(0, j));
    for (int i = 0; i < kRings; ++i) {
      m.faces.emplace_back(at(i, j), at(i, j + 1), at(i + 1, j + 1));
      m.faces.emplace_back(at(i, j), at(i + 1, j + 1), at(i + 1, j));
    }
    m.faces.emplace_back(top, at(kRings, j), at(kRings, j + 1));
  }
  m.compute_vertex_normals();
  Scene s;
  s.name = "vase";
  s.surfaces.push_back({std::move(m), Texture::kPatches});
  s.table_from_camera = look_at({0, -0.36, 0.24}, {0, 0, 0.08}, 1.5);
  s.light_dir_lab = Vector3d(-0.3, -0.8, 0.6).normalized();
  return s;
}

Scene fuzzy(uint64_t seed) {
  Scene s;
  s.name = "fuzzy";
  const Vector3f centre(0, 0, 0.11f);
  const float core_r = 0.035f;
  Mesh core = uv_sphere(centre, core_r, 32, 64);
  core.compute_vertex_normals();
  s.surfaces.push_back({std::move(core), Texture::kPatches});
  // A textured pot under the fuzz: solid geometry the sensor does measure.
  Mesh pot = box({-0.035f, -0.035f, 0.0f}, {0.035f, 0.035f, 0.075f}, false);
  pot.compute_vertex_normals();
  s.surfaces.push_back({std::move(pot), Texture::kPatches});

  std::mt19937_64 rng(seed ^ 0x5eedf0220ULL);
  std::normal_distribution<float> gauss(0, 1);
  std::uniform_real_distribution<float> uni(0, 1);
  const int n_strands = 1500, n_seg = 4;
  for (int i = 0; i < n_strands; ++i) {
    Vector3f dir(gauss(rng), gauss(rng), gauss(rng));
    dir.normalize();
    if (dir.z() < -0.3f) dir.z() = -dir.z();  // the pot holds the lower half
    const float length = 0.03f + 0.03f * uni(rng);
    const float radius = 0.00025f + 0.0001f * uni(rng);  // 0.5-0.7 mm wide
    Vector3f p = centre + dir * core_r * 0.98f;
    Vector3f heading = dir;
    const Vector3f colour(0.35f + 0.4f * uni(rng), 0.55f + 0.35f * uni(rng), 0.1f + 0.15f * uni(rng));
    const uint32_t first = static_cast<uint32_t>(s.strands.points.size());
    s.strands.points.emplace_back(p.x(), p.y(), p.z(), radius);
    for (int k = 0; k < n_seg; ++k) {
      heading = (heading + 0.35f * Vector3f(gauss(rng), gauss(rng), gauss(rng)) -
                 0.15f * Vector3f::UnitZ()).normalized();
      p += heading * (length / n_seg);
      s.strands.points.emplace_back(p.x(), p.y(), p.z(), radius * (1 - 0.15f * float(k + 1)));
      s.strands.segments.push_back(first + static_cast<uint32_t>(k));
      s.strands.colors.push_back(colour);
    }
  }
  s.table_from_camera = look_at({0, -0.36, 0.22}, {0, 0, 0.085}, 1.5);
  s.light_dir_lab = Vector3d(-0.3, -0.8, 0.6).normalized();
  return s;
}

Scene room() {
  Scene s;
  s.name = "room";
  s.layout = Layout::kCameraCentre;
  auto add = [&](Mesh m, Texture t) {
    m.compute_vertex_normals();
    s.surfaces.push_back({std::move(m), t});
  };
  add(box({-2.5f, -2.0f, 0.0f}, {2.7f, 2.2f, 2.6f}, true), Texture::kWalls);
  add(box({1.2f, -0.6f, 0.0f}, {2.0f, 0.4f, 0.75f}, false), Texture::kPatches);   // table
  add(box({-1.9f, 1.2f, 0.0f}, {-1.2f, 2.1f, 1.8f}, false), Texture::kPatches);   // shelf
  add(box({-0.8f, -1.9f, 0.0f}, {0.3f, -1.3f, 0.45f}, false), Texture::kPatches); // bench
  add(uv_sphere({1.5f, -0.1f, 0.9f}, 0.15f, 24, 48), Texture::kPatches);          // ball on the table
  // The camera rides the table 8 cm off the axis, looking out and slightly down.
  s.table_from_camera = look_at({0.08, 0, 1.3}, {2.0, 0.05, 1.1}, 0.5);
  s.light_dir_lab = Vector3d(0.2, 0.3, 1).normalized();
  s.far_m = 12;
  return s;
}

// A chessboard on a stand, leaning back 20 degrees, its printed side facing the
// camera at table angle 0; a 15 mm white margin around 10x7 squares of 20 mm.
Scene board() {
  Scene s;
  s.name = "board";
  const double sq = 0.02, margin = 0.015;
  const double w = 10 * sq + 2 * margin, h = 7 * sq + 2 * margin;
  // Board frame: origin at the first inner corner; x right, y down the board, z into it.
  Eigen::Isometry3d world_from_board = Eigen::Isometry3d::Identity();
  const double lean = 20.0 * std::numbers::pi / 180;
  const Vector3d x = Vector3d::UnitX();
  const Vector3d y = Vector3d(0, -std::sin(lean), -std::cos(lean));  // down the board
  const Vector3d z = x.cross(y);  // into the board, away from the camera at angle 0
  world_from_board.linear().col(0) = x;
  world_from_board.linear().col(1) = y;
  world_from_board.linear().col(2) = z;
  const Vector3d top_left = Vector3d(-w / 2, 0.03 + std::sin(lean) * h, 0.03 + std::cos(lean) * h);
  world_from_board.translation() = top_left + (margin + sq) * x + (margin + sq) * y;
  Mesh m;
  const Vector3d o = top_left;
  for (const Vector3d& c : std::array<Vector3d, 4>{o, o + w * x, o + w * x + h * y, o + h * y})
    m.vertices.push_back(c.cast<float>());
  m.faces = {{0, 2, 1}, {0, 3, 2}};
  m.compute_vertex_normals();
  s.surfaces.push_back({std::move(m), Texture::kChessboard});
  s.world_from_board = world_from_board;
  s.board_squares_x = 10;
  s.board_squares_y = 7;
  s.board_square_m = sq;
  s.table_from_camera = look_at({0, -0.42, 0.30}, {0, 0, 0.10}, 1.5);
  s.light_dir_lab = Vector3d(0.1, -0.9, 0.5).normalized();
  return s;
}

}  // namespace

std::vector<std::string> scene_names() {
  return {"bunny", "fuzzy", "room", "blob", "vase", "board", "board_wobble"};
}

Result<Scene> make_scene(const std::string& name, uint64_t seed, const fs::path& data_dir) {
  if (name == "bunny") return bunny(data_dir);
  if (name == "fuzzy") return fuzzy(seed);
  if (name == "room") return room();
  if (name == "blob") return blob();
  if (name == "vase") return vase();
  if (name == "board") return board();
  if (name == "board_wobble") {
    Scene s = board();
    s.name = "board_wobble";
    s.camera_wobble_deg = 20;
    s.wobble_centre = Vector3d(0, 0, 0.10);
    // Closer, so the board covers more of the image (distortion and focal length separate).
    s.table_from_camera = look_at({0, -0.30, 0.22}, {0, 0, 0.10}, 1.5);
    return s;
  }
  return fail("unknown scene '" + name + "' (choose bunny, fuzzy, room, blob, vase, board or board_wobble)");
}

}  // namespace s2r::synth
