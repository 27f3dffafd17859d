#include "capture/import_datasets.h"

#include <algorithm>
#include <cstring>
#include <map>
#include <set>
#include <fstream>
#include <regex>
#include <sstream>

#include <fmt/format.h>

#include "capture/colmap_model.h"
#include "capture/session.h"
#include "capture/stanford_conf.h"
#include "core/image_io.h"
#include "core/atomic_file.h"
#include "core/json_fields.h"
#include "core/paths.h"
#include "core/mesh.h"
#include "core/progress.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

Eigen::Isometry3d orthonormalised(const Eigen::Matrix4d& m) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(m.topLeftCorner<3, 3>(), Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = svd.matrixU() * svd.matrixV().transpose();
  t.translation() = m.topRightCorner<3, 1>();
  return t;
}

ImageU8 to_rgb(ImageU8 im) {
  if (im.channels == 3) return im;
  ImageU8 out(im.width, im.height, 3);
  for (int y = 0; y < im.height; ++y)
    for (int x = 0; x < im.width; ++x)
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = im.at(x, y, im.channels >= 3 ? c : 0);
  return out;
}

bool take(int i, const ImportOptions& o, int taken) {
  if (i % std::max(1, o.stride) != 0) return false;
  return o.max_frames <= 0 || taken < o.max_frames;
}

struct Importer {
  Session header;
  std::optional<SessionWriter> writer;
  Report report;

  Status begin(const fs::path& out, const std::string& source) {
    header.root = out;
    header.name = out.filename().string();
    header.source = "import:" + source;
    auto w = SessionWriter::create(header);
    if (!w) return std::unexpected(w.error());
    writer.emplace(std::move(*w));
    report.stage = "import";
    report.params["dataset"] = source;
    return {};
  }
};

// --- Stanford .conf -------------------------------------------------------------
Result<Report> stanford(const fs::path& conf_path, const fs::path& out, const ImportOptions& o) {
  auto conf = read_stanford_conf(conf_path);
  if (!conf) return std::unexpected(conf.error());
  const fs::path conf_dir = conf_path.parent_path();
  const auto& entries = conf->scans;
  Importer im;
  im.header.layout = Layout::kObjectCentre;
  im.header.notes.push_back("Stanford range scans; world_from_camera is the .conf pose "
                            "(tx ty tz qx qy qz qw), i.e. world_from_scan");
  if (auto st = im.begin(out, "stanford"); !st) return std::unexpected(st.error());
  Progress progress("import stanford", entries.size());
  int taken = 0;
  size_t points = 0;
  for (size_t i = 0; i < entries.size(); ++i, progress.tick()) {
    if (!take(static_cast<int>(i), o, taken)) continue;
    auto scan = read_ply_points(conf_dir / entries[i].file);
    if (!scan) return std::unexpected(scan.error());
    Frame f;
    f.index = taken;
    f.points = "points/" + frame_file_name(taken, "ply");
    f.source = entries[i].file;
    f.world_from_camera = entries[i].world_from_scan;
    if (auto st = write_ply_points(out / f.points, *scan); !st) return std::unexpected(st.error());
    if (auto st = im.writer->add_frame(f, nullptr, nullptr); !st) return std::unexpected(st.error());
    points += scan->points.size();
    ++taken;
  }
  im.report.counts["frames"] = taken;
  im.report.counts["points"] = double(points);
  return im.report;
}

// --- Middlebury multi-view (K R t per image) -------------------------------------
Result<Report> middlebury(const fs::path& path, const fs::path& out, const ImportOptions& o) {
  fs::path par = path;
  if (fs::is_directory(path)) {
    par.clear();
    for (const auto& e : fs::directory_iterator(path))
      if (e.path().filename().string().ends_with("_par.txt")) par = e.path();
    if (par.empty()) return fail("'" + path.string() + "': no *_par.txt file");
  }
  std::ifstream in(par);
  int count = 0;
  if (!(in >> count) || count <= 0) return fail(par.string() + ": first line must be the image count");
  Importer im;
  im.header.layout = Layout::kObjectCentre;
  im.header.notes.push_back("Middlebury multi-view: P = K [R t], world_from_camera = inverse([R t])");
  if (auto st = im.begin(out, "middlebury"); !st) return std::unexpected(st.error());
  Progress progress("import middlebury", static_cast<size_t>(count));
  int taken = 0;
  for (int i = 0; i < count; ++i, progress.tick()) {
    std::string name;
    double v[21];
    if (!(in >> name)) return fail(par.string() + ": expected " + std::to_string(count) + " lines, got " + std::to_string(i));
    for (double& x : v)
      if (!(in >> x) || !std::isfinite(x)) return fail(par.string() + ": line for '" + name + "' needs 21 finite numbers");
    if (!take(i, o, taken)) continue;
    auto img = read_image_u8(par.parent_path() / name);
    if (!img) return std::unexpected(img.error());
    Intrinsics K;
    K.width = img->width;
    K.height = img->height;
    K.fx = v[0]; K.cx = v[2]; K.fy = v[4]; K.cy = v[5];
    if (auto st = K.validate(par.string() + ": " + name); !st) return std::unexpected(st.error());
    Eigen::Matrix4d cw = Eigen::Matrix4d::Identity();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) cw(r, c) = v[9 + 3 * r + c];
      cw(r, 3) = v[18 + r];
    }
    Frame f;
    f.index = taken;
    f.source = name;
    f.intrinsics = K;
    f.world_from_camera = orthonormalised(cw).inverse();
    if (!im.header.color) {
      im.header.color = ColorSensor{"import", "middlebury", "RGB8", K, 0, 0};
      im.writer->mutable_header().color = im.header.color;
    }
    ImageU8 rgb = to_rgb(std::move(*img));
    if (auto st = im.writer->add_frame(f, &rgb, nullptr); !st) return std::unexpected(st.error());
    ++taken;
  }
  im.report.counts["frames"] = taken;
  return im.report;
}

// --- RealSense D435 (depth aligned to colour, mm) --------------------------------
Result<Report> realsense(const fs::path& dir, const fs::path& out, const ImportOptions& o) {
  auto pair_for = [&](int i) -> std::optional<std::pair<fs::path, fs::path>> {
    const std::string n = std::to_string(i);
    const std::pair<fs::path, fs::path> layouts[] = {
        {dir / "color" / ("color_" + n + ".png"), dir / "depth" / ("depth_" + n + ".png")},
        {dir / ("rgb_" + n + ".png"), dir / ("depth_" + n + ".png")}};
    for (const auto& p : layouts)
      if (fs::exists(p.first) && fs::exists(p.second)) return p;
    return std::nullopt;
  };
  if (!pair_for(0))
    return fail("'" + dir.string() + "': expected color/color_0.png + depth/depth_0.png or rgb_0.png + depth_0.png");
  Intrinsics K;  // the capture code's values for this D435 (PROVENANCE.txt)
  K.width = 640; K.height = 480;
  K.fx = 616.8676; K.fy = 617.0631; K.cx = 319.5701; K.cy = 233.0649;
  Importer im;
  im.header.layout = Layout::kObjectCentre;
  im.header.color = ColorSensor{"import", "realsense-d435", "RGB8", K, 0, 0};
  DepthSensor ds;
  ds.driver = "import";
  ds.device = "realsense-d435";
  ds.intrinsics = K;
  ds.unit_m = 0.001;
  ds.aligned_to_color = true;
  im.header.depth = ds;
  im.header.notes.push_back("RealSense D435, depth aligned to colour (rs.align); no poses, table angles unknown");
  if (auto st = im.begin(out, "realsense"); !st) return std::unexpected(st.error());
  int taken = 0;
  for (int i = 0; auto files = pair_for(i); ++i) {
    if (!take(i, o, taken)) continue;
    auto color = read_image_u8(files->first);
    if (!color) return std::unexpected(color.error());
    auto depth = read_image_u16(files->second);
    if (!depth) return std::unexpected(depth.error());
    if (color->width != K.width || depth->width != K.width || depth->channels != 1)
      return fail("'" + files->second.string() + "': expected 640x480 colour and 1-channel depth");
    Frame f;
    f.index = taken;
    f.source = files->first.filename().string();
    ImageU8 rgb = to_rgb(std::move(*color));
    if (auto st = im.writer->add_frame(f, &rgb, &*depth); !st) return std::unexpected(st.error());
    ++taken;
  }
  im.report.counts["frames"] = taken;
  return im.report;
}

// --- Microsoft 7-Scenes --------------------------------------------------------
Result<Report> sevenscenes(const fs::path& dir, const fs::path& out, const ImportOptions& o) {
  std::ifstream kin(dir / "camera-intrinsics.txt");
  double k[9];
  for (double& x : k)
    if (!(kin >> x)) return fail("'" + (dir / "camera-intrinsics.txt").string() + "': expected a 3x3 matrix");
  std::vector<fs::path> colors;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.path().filename().string().ends_with(".color.jpg") || e.path().filename().string().ends_with(".color.png"))
      colors.push_back(e.path());
  std::sort(colors.begin(), colors.end());
  if (colors.empty()) return fail("'" + dir.string() + "': no frame-*.color.jpg");
  Intrinsics K;
  K.width = 640; K.height = 480;
  K.fx = k[0]; K.cx = k[2]; K.fy = k[4]; K.cy = k[5];
  if (auto st = K.validate("camera-intrinsics.txt"); !st) return std::unexpected(st.error());
  Importer im;
  im.header.layout = Layout::kCameraCentre;
  im.header.color = ColorSensor{"import", "kinect-v1", "RGB8", K, 0, 0};
  DepthSensor ds;
  ds.driver = "import";
  ds.device = "kinect-v1";
  ds.intrinsics = K;
  ds.unit_m = 0.001;
  im.header.depth = ds;
  im.header.notes.push_back("7-Scenes: depth and colour come from different, unregistered sensors; "
                            "colour_from_depth is unknown (identity); 65535 depth mapped to 0");
  if (auto st = im.begin(out, "7scenes"); !st) return std::unexpected(st.error());
  Progress progress("import 7scenes", colors.size());
  int taken = 0;
  for (size_t i = 0; i < colors.size(); ++i, progress.tick()) {
    if (!take(static_cast<int>(i), o, taken)) continue;
    std::string stem = colors[i].filename().string();
    stem = stem.substr(0, stem.find(".color."));
    auto color = read_image_u8(colors[i]);
    if (!color) return std::unexpected(color.error());
    auto depth = read_image_u16(dir / (stem + ".depth.png"));
    if (!depth) return std::unexpected(depth.error());
    for (auto& d : depth->data)
      if (d == 65535) d = 0;
    std::ifstream pin(dir / (stem + ".pose.txt"));
    Eigen::Matrix4d m;
    for (int r = 0; r < 16; ++r)
      if (!(pin >> m(r / 4, r % 4)) || !std::isfinite(m(r / 4, r % 4)))
        return fail("'" + (dir / (stem + ".pose.txt")).string() + "': expected a 4x4 matrix");
    Frame f;
    f.index = taken;
    f.source = stem;
    f.world_from_camera = orthonormalised(m);
    ImageU8 rgb = to_rgb(std::move(*color));
    if (auto st = im.writer->add_frame(f, &rgb, &*depth); !st) return std::unexpected(st.error());
    ++taken;
  }
  im.report.counts["frames"] = taken;
  return im.report;
}


// --- NeRF / nerfstudio / instant-ngp transforms.json -----------------------------
//
// Pixel centres: Blender renders pixel (i, j) at (i + 0.5, j + 0.5) with the
// principal point at the image centre, and nerfstudio and instant-ngp give cx,
// cy in that continuous convention too; this project's intrinsics put pixel
// centres at integers (OpenCV), so cx = cx' - 0.5.

// Which transforms file a path names.
Result<fs::path> transforms_file(const fs::path& path, const std::string& split) {
  if (fs::is_regular_file(path)) return path;
  const fs::path named = path / ("transforms_" + (split.empty() ? std::string("train") : split) + ".json");
  if (!split.empty()) {
    if (!fs::exists(named)) return fail(ErrorCode::not_found, "'" + path.string() + "': no transforms_" + split + ".json");
    return named;
  }
  if (fs::exists(path / "transforms.json")) return path / "transforms.json";
  if (fs::exists(named)) return named;
  return fail(ErrorCode::not_found, "'" + path.string() + "': no transforms.json nor transforms_train.json");
}

// A frame's file: as written, else with the extensions Blender's scenes leave out.
Result<fs::path> frame_image(const fs::path& base, const std::string& rel) {
  const fs::path p = base / rel;
  for (const char* ext : {"", ".png", ".jpg", ".jpeg", ".PNG", ".JPG"}) {
    fs::path q = p;
    q += ext;
    if (fs::is_regular_file(q)) return q;
  }
  return fail(ErrorCode::not_found, "'" + p.string() + "': image not found (tried .png and .jpg too)");
}

// The camera of a frame from its own keys, else the file's (global) ones.
Intrinsics nerf_intrinsics(const FieldReader& frame, const FieldReader& top, int width, int height) {
  auto number = [&](const char* key) -> std::optional<double> {
    if (frame.has(key)) return frame.number(key);
    if (top.has(key)) return top.number(key);
    return std::nullopt;
  };
  Intrinsics K;
  K.width = width;
  K.height = height;
  const auto fl_x = number("fl_x"), fl_y = number("fl_y"), ax = number("camera_angle_x"), ay = number("camera_angle_y");
  if (fl_x) K.fx = *fl_x;
  else if (ax) K.fx = 0.5 * width / std::tan(0.5 * *ax);
  else frame.error("fl_x", "neither fl_x nor camera_angle_x is given");
  if (fl_y) K.fy = *fl_y;
  else if (ay) K.fy = 0.5 * height / std::tan(0.5 * *ay);
  else K.fy = K.fx;
  K.cx = number("cx").value_or(0.5 * width) - 0.5;
  K.cy = number("cy").value_or(0.5 * height) - 0.5;
  const char* dist[] = {"k1", "k2", "p1", "p2", "k3"};
  for (size_t i = 0; i < 5; ++i) K.dist[i] = number(dist[i]).value_or(0.0);
  return K;
}

// A 4x4 matrix as four rows of four numbers; its rotation proper and
// orthonormal within 1e-3 (a scaled camera-to-world is not a camera pose).
Eigen::Matrix4d nested_matrix4(const FieldReader& m) {
  if (m.array_size() != 4) m.error("expected 4 rows of 4 numbers");
  Eigen::Matrix4d a;
  for (size_t r = 0; r < 4; ++r) {
    FieldReader row = m.index(r);
    if (row.array_size() != 4) row.error("expected 4 numbers");
    for (size_t c = 0; c < 4; ++c) {
      const auto& v = row.raw()[c];
      if (!v.is_number() || !std::isfinite(v.get<double>())) row.error("element " + std::to_string(c) + " is not a finite number");
      a(Eigen::Index(r), Eigen::Index(c)) = v.get<double>();
    }
  }
  const Eigen::Matrix3d R = a.topLeftCorner<3, 3>();
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-3 || R.determinant() < 0)
    m.error("rotation part is not a proper rotation (R^T R != I or det < 0)");
  return a;
}

// transform_matrix: camera-to-world, camera axes x right, y up, looking along -z.
Eigen::Isometry3d opencv_from_opengl_pose(const Eigen::Matrix4d& c2w) {
  Eigen::Isometry3d t = orthonormalised(c2w);
  t.linear() = t.linear() * Eigen::Vector3d(1, -1, -1).asDiagonal();
  return t;
}

Result<Report> nerf(const fs::path& path, const fs::path& out, const ImportOptions& o) {
  auto file = transforms_file(path, o.split);
  if (!file) return std::unexpected(file.error());
  auto j = parse_json_file(*file);
  if (!j) return std::unexpected(j.error());
  const std::array<float, 3> bg = o.background.value_or(std::array<float, 3>{1.f, 1.f, 1.f});
  Importer im;
  im.header.layout = Layout::kObjectCentre;
  im.header.notes.push_back("transforms.json (" + file->filename().string() +
                            "): camera-to-world in OpenGL axes, turned to OpenCV's; principal point moved by -0.5 px "
                            "(pixel centres at integers)");
  std::vector<std::pair<Frame, fs::path>> frames;
  try {
    FieldReader top(*j, file->filename().string());
    FieldReader list = top.at("frames");
    const fs::path base = file->parent_path();
    for (size_t i = 0; i < list.array_size(); ++i) {
      FieldReader fr = list.index(i);
      Frame f;
      f.source = fr.string("file_path");
      auto img = frame_image(base, f.source);
      if (!img) fr.error("file_path", img.error().message);
      f.world_from_camera = opencv_from_opengl_pose(nested_matrix4(fr.at("transform_matrix")));
      frames.push_back({std::move(f), *img});
    }
    if (frames.empty()) top.error("frames", "no frame");
    // Image sizes may be left out (Blender): the first frame's file says.
    auto info = probe_image(frames.front().second);
    if (!info) return std::unexpected(info.error());
    for (size_t i = 0; i < frames.size(); ++i) {
      FieldReader fr = list.index(i);
      const int w = int(fr.has("w") ? fr.integer("w") : top.has("w") ? top.integer("w") : info->width);
      const int h = int(fr.has("h") ? fr.integer("h") : top.has("h") ? top.integer("h") : info->height);
      frames[i].first.intrinsics = nerf_intrinsics(fr, top, w, h);
      if (auto st = frames[i].first.intrinsics->validate(file->string() + ": frames[" + std::to_string(i) + "]"); !st)
        return std::unexpected(st.error());
    }
  } catch (const FormatError& e) {
    return fail(ErrorCode::format, e.what());
  }
  if (auto st = im.begin(out, "nerf"); !st) return std::unexpected(st.error());
  Progress progress("import nerf", frames.size());
  int taken = 0;
  size_t with_alpha = 0;
  for (size_t i = 0; i < frames.size(); ++i, progress.tick()) {
    if (!take(static_cast<int>(i), o, taken)) continue;
    auto& [f, image] = frames[i];
    auto img = read_image_u8(image);
    if (!img) return std::unexpected(img.error());
    const Intrinsics& K = *f.intrinsics;
    if (img->width != K.width || img->height != K.height)
      return fail(ErrorCode::format, fmt::format("'{}' is {}x{} but {} says {}x{}", image.string(), img->width, img->height,
                                                 file->filename().string(), K.width, K.height));
    f.index = taken;
    std::optional<ImageU8> matte;
    if (img->channels == 4) {
      ImageU8 rgb(img->width, img->height, 3);
      matte = ImageU8(img->width, img->height, 1);
      for (size_t p = 0; p < rgb.pixels(); ++p) {
        const int a = img->data[p * 4 + 3];
        matte->data[p] = uint8_t(a);
        for (size_t c = 0; c < 3; ++c)
          rgb.data[p * 3 + c] = uint8_t(std::lround((img->data[p * 4 + c] * a + bg[c] * 255.f * (255 - a)) / 255.f));
      }
      *img = std::move(rgb);
      ++with_alpha;
    } else {
      *img = to_rgb(std::move(*img));
    }
    if (!im.header.color) {
      im.header.color = ColorSensor{"import", "nerf", "RGB8", K, 0, 0};
      im.writer->mutable_header().color = im.header.color;
    }
    if (matte && !im.writer->session().background) im.writer->mutable_header().background = bg;
    if (auto st = im.writer->add_frame(f, &*img, nullptr, matte ? &*matte : nullptr); !st) return std::unexpected(st.error());
    ++taken;
  }
  progress.done();
  im.report.counts["frames"] = taken;
  im.report.counts["frames_with_matte"] = double(with_alpha);
  im.report.params["transforms"] = file->string();
  if (with_alpha) im.report.params["background"] = fmt::format("{},{},{}", bg[0], bg[1], bg[2]);
  return im.report;
}

// DIR may be the model folder itself, or a project with sparse/0 (COLMAP's
// mapper) or sparse/ under it; images come from --images, else DIR/images, else
// beside the model.
Result<Report> colmap(const fs::path& path, const fs::path& out, const ImportOptions& o) {
  fs::path dir;
  for (const fs::path& c : {path, path / "sparse" / "0", path / "sparse"})
    if (fs::exists(c / "cameras.txt") || fs::exists(c / "cameras.bin")) {
      dir = c;
      break;
    }
  if (dir.empty()) return fail(ErrorCode::not_found, "'" + path.string() + "': no cameras.txt or cameras.bin (nor under sparse/0)");
  auto model = read_colmap_model(dir);
  if (!model) return std::unexpected(model.error());
  if (model->images.empty()) return fail(ErrorCode::format, "'" + dir.string() + "': no registered image");
  fs::path images = o.images;
  if (images.empty()) images = fs::exists(path / "images") ? path / "images" : dir;
  Importer im;
  im.header.layout = Layout::kObjectCentre;
  im.header.notes.push_back("COLMAP " + model->encoding + " model (" + dir.string() +
                            "): cam_from_world inverted; principal point moved by -0.5 px (pixel centres at integers)");
  for (const auto& img : model->images)
    if (!model->cameras.count(img.camera))
      return fail(ErrorCode::format, fmt::format("'{}': image {} ('{}') names camera {}, which is not in the model", dir.string(),
                                                 img.id, img.name, img.camera));
  if (auto st = im.begin(out, "colmap"); !st) return std::unexpected(st.error());
  Progress progress("import colmap", model->images.size());
  int taken = 0;
  std::set<std::string> models;
  for (size_t i = 0; i < model->images.size(); ++i, progress.tick()) {
    if (!take(int(i), o, taken)) continue;
    const ColmapImage& c = model->images[i];
    const ColmapCamera& cam = model->cameras.at(c.camera);
    auto file = resolve_inside(images, c.name);
    if (!file) return std::unexpected(file.error());
    auto img = read_image_u8(*file);
    if (!img) return std::unexpected(img.error());
    if (img->width != cam.K.width || img->height != cam.K.height)
      return fail(ErrorCode::format, fmt::format("'{}' is {}x{} but its camera {} says {}x{}", file->string(), img->width,
                                                 img->height, c.camera, cam.K.width, cam.K.height));
    Frame f;
    f.index = taken;
    f.source = c.name;
    f.intrinsics = cam.K;
    f.world_from_camera = c.cam_from_world.inverse();
    if (!im.header.color) {
      im.header.color = ColorSensor{"import", "colmap", "RGB8", cam.K, 0, 0};
      im.writer->mutable_header().color = im.header.color;
    }
    models.insert(cam.model);
    ImageU8 rgb = to_rgb(std::move(*img));
    if (auto st = im.writer->add_frame(f, &rgb, nullptr); !st) return std::unexpected(st.error());
    ++taken;
  }
  progress.done();
  im.report.counts["frames"] = taken;
  im.report.counts["cameras"] = double(model->cameras.size());
  im.report.counts["points3d"] = double(model->points3d);
  if (model->points3d) im.report.errors["points3d_mean_reprojection_px"] = model->mean_track_error_px;
  im.report.params["encoding"] = model->encoding;
  std::string names;
  for (const auto& n : models) names += (names.empty() ? "" : ",") + n;
  im.report.params["camera_models"] = names;
  return im.report;
}

}  // namespace

Result<Report> import_dataset(const std::string& kind, const fs::path& path, const fs::path& out,
                              const ImportOptions& options) {
  Stopwatch clock;
  std::error_code ec;
  if (!fs::exists(path, ec)) return fail("'" + path.string() + "': not found");
  Result<Report> r = fail("unknown data set '" + kind + "' (choose stanford, middlebury, realsense, 7scenes, nerf or colmap)");
  if (kind == "stanford") r = stanford(path, out, options);
  else if (kind == "middlebury") r = middlebury(path, out, options);
  else if (kind == "realsense") r = realsense(path, out, options);
  else if (kind == "7scenes") r = sevenscenes(path, out, options);
  else if (kind == "nerf") r = nerf(path, out, options);
  else if (kind == "colmap") r = colmap(path, out, options);
  if (r) r->seconds = clock.seconds();
  return r;
}

}  // namespace s2r
