#include "render/envmap.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>

#include <spdlog/fmt/fmt.h>

#include "core/image_io.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/report.h"

namespace s2r {
namespace fs = std::filesystem;

namespace {

constexpr int kFormatVersion = 1;

// One level of a solid-angle-weighted pyramid of the panorama: every pixel is
// the mean radiance over its solid angle, at the grid direction of its centre.
struct Level {
  int width = 0, height = 0;
  double spacing = 0;                 // the larger of the pixel's angular sides, radians
  std::vector<Eigen::Vector3f> rgb;   // x fastest
  std::vector<Eigen::Vector3f> dir;   // unit, float
  std::vector<float> area;            // solid angle of one pixel of row y
};

// The brightest pixels (a sun) as a sparse list of their radiance above a
// level B: the pyramid holds min(P, B) (same chroma), and every lobe adds the
// excess of these pixels exactly, at their own directions, wherever the
// weight times the excess can matter. Without it, a sun 10^4 times the sky
// just outside a lobe's cap would be lost (weights below th x peak dropped)
// or, on a coarse level, moved to the centre of a big pixel.
struct Bright {
  std::vector<Eigen::Vector3f> dir, excess;
  std::vector<float> area;
  float level = 0;           // B, luminance
  float largest_excess = 0;  // luminance
};

constexpr double kBrightOverMean = 64;   // pixels above 64 x the mean luminance ...
constexpr size_t kBrightMax = 1024;      // ... the 1024 brightest at most
const Eigen::Vector3f kLuma(0.2126f, 0.7152f, 0.0722f);

struct Pyramid {
  std::vector<Level> levels;
  Bright bright;
};

Pyramid build_pyramid(const Panorama& pano) {
  Pyramid out;
  std::vector<Level>& levels = out.levels;
  levels.resize(1);
  Level& base = levels[0];
  base.width = pano.width();
  base.height = pano.height();
  base.rgb.resize(static_cast<size_t>(base.width) * base.height);
  base.dir.resize(base.rgb.size());
  base.area.resize(base.height);
  for (int y = 0; y < base.height; ++y) {
    base.area[y] = static_cast<float>(pano.solid_angle(y));
    for (int x = 0; x < base.width; ++x) {
      const size_t i = static_cast<size_t>(y) * base.width + x;
      base.rgb[i] = pano.at(x, y);
      base.dir[i] = pano.unit(x, y).cast<float>();
    }
  }
  {
    double mean = 0, total = 0;
    std::vector<float> luma(base.rgb.size());
    for (size_t i = 0; i < luma.size(); ++i) {
      luma[i] = base.rgb[i].dot(kLuma);
      mean += luma[i] * base.area[i / base.width];
      total += base.area[i / base.width];
    }
    mean /= total;
    std::vector<float> sorted = luma;
    const size_t n = std::min(kBrightMax, sorted.size() - 1);
    std::nth_element(sorted.begin(), sorted.begin() + n, sorted.end(), std::greater<float>());
    const float level = std::max(static_cast<float>(kBrightOverMean * mean), sorted[n]);
    out.bright.level = level;
    for (size_t i = 0; i < luma.size(); ++i)
      if (luma[i] > level && out.bright.dir.size() < kBrightMax) {
        const float keep = level / luma[i];
        out.bright.dir.push_back(base.dir[i]);
        out.bright.excess.push_back(base.rgb[i] * (1 - keep));
        out.bright.area.push_back(base.area[i / base.width]);
        out.bright.largest_excess = std::max(out.bright.largest_excess, luma[i] - level);
        base.rgb[i] *= keep;
      }
  }
  // Halve while both sides are even and the result keeps at least 8 x 4 pixels.
  while (levels.back().width % 2 == 0 && levels.back().height % 2 == 0 && levels.back().height >= 8 &&
         levels.back().width >= 16) {
    const Level& f = levels.back();
    Level c;
    c.width = f.width / 2;
    c.height = f.height / 2;
    c.rgb.resize(static_cast<size_t>(c.width) * c.height);
    c.dir.resize(c.rgb.size());
    c.area.resize(c.height);
    for (int y = 0; y < c.height; ++y) {
      const double a0 = f.area[2 * y], a1 = f.area[2 * y + 1];
      c.area[y] = static_cast<float>(2 * (a0 + a1));
      for (int x = 0; x < c.width; ++x) {
        const size_t i = static_cast<size_t>(y) * c.width + x;
        const auto px = [&](int xx, int yy) { return f.rgb[static_cast<size_t>(yy) * f.width + xx].cast<double>(); };
        const Eigen::Vector3d sum = a0 * (px(2 * x, 2 * y) + px(2 * x + 1, 2 * y)) + a1 * (px(2 * x, 2 * y + 1) + px(2 * x + 1, 2 * y + 1));
        c.rgb[i] = (sum / (2 * (a0 + a1))).cast<float>();
        // The pixel's direction is the centroid of its energy (luminance x solid
        // angle) over its four children: a sun smaller than a coarse pixel stays
        // where it is instead of moving to the pixel's centre. A black pixel
        // keeps its grid centre.
        Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
        for (int dy = 0; dy < 2; ++dy)
          for (int dx = 0; dx < 2; ++dx) {
            const size_t ci = static_cast<size_t>(2 * y + dy) * f.width + 2 * x + dx;
            const double energy = (dy ? a1 : a0) * static_cast<double>(f.rgb[ci].dot(kLuma));
            centroid += energy * f.dir[ci].cast<double>();
          }
        if (centroid.norm() > 0) {
          c.dir[i] = centroid.normalized().cast<float>();
        } else {
          c.dir[i] = equirect_direction(x, y, c.width, c.height).cast<float>();
        }
      }
    }
    levels.push_back(std::move(c));
  }
  for (Level& l : levels) l.spacing = std::max(M_PI / l.height, 2 * M_PI / l.width);
  return out;
}

struct Scratch {
  std::vector<float> log_weight, area;
  std::vector<const Eigen::Vector3f*> colour;
};

// The normalised lobe about unit u with exponent L, summed over the cap of
// half-angle `cap` on pyramid level `lv`.
Eigen::Vector3f lobe(const Level& lv, const Bright& bright, const Eigen::Vector3d& u, double L, double cap,
                     float bright_cos, Scratch& s, double* samples) {
  s.log_weight.clear();
  s.area.clear();
  s.colour.clear();
  const Eigen::Vector3f uf = u.cast<float>();
  const float Lf = static_cast<float>(L);
  const double window = std::min(M_PI, cap + 0.75 * lv.spacing);
  const double lat0 = std::asin(std::clamp(u.y(), -1.0, 1.0));
  const double lon0 = std::atan2(u.x(), -u.z());
  const int H = lv.height, W = lv.width;
  const int y0 = std::max(0, static_cast<int>(std::ceil((M_PI / 2 - (lat0 + window)) * H / M_PI - 0.5)));
  const int y1 = std::min(H - 1, static_cast<int>(std::floor((M_PI / 2 - (lat0 - window)) * H / M_PI - 0.5)));
  const double cos_w = std::cos(window), sin_lat0 = std::sin(lat0), cos_lat0 = std::cos(lat0);
  // log of (u.w)^L from the chord: no cancellation where cos is near 1.
  const auto log_weight = [&](const Eigen::Vector3f& w) { return Lf == 0 ? 0.f : Lf * std::log1p(-0.5f * (uf - w).squaredNorm()); };
  float top = -std::numeric_limits<float>::infinity();
  for (int y = y0; y <= y1; ++y) {
    const double lat = M_PI / 2 - M_PI * (y + 0.5) / H;
    const double den = cos_lat0 * std::cos(lat);
    int x0 = 0, count = W;
    if (den > 1e-12) {
      const double c = (cos_w - sin_lat0 * std::sin(lat)) / den;
      if (c > 1) continue;
      if (c > -1) {
        const double half = std::acos(c);
        x0 = static_cast<int>(std::ceil((lon0 - half + M_PI) * W / (2 * M_PI) - 0.5));
        const int x1 = static_cast<int>(std::floor((lon0 + half + M_PI) * W / (2 * M_PI) - 0.5));
        count = std::min(W, x1 - x0 + 1);
        if (count <= 0) continue;
      }
    }
    const float area = lv.area[y];
    const size_t row = static_cast<size_t>(y) * W;
    for (int n = 0; n < count; ++n) {
      const int x = ((x0 + n) % W + W) % W;
      const Eigen::Vector3f& w = lv.dir[row + x];
      if (uf.dot(w) <= 0) continue;
      const float lw = log_weight(w);
      s.log_weight.push_back(lw);
      s.area.push_back(area);
      s.colour.push_back(&lv.rgb[row + x]);
      top = std::max(top, lw);
    }
  }
  *samples += static_cast<double>(s.log_weight.size());
  if (s.log_weight.empty()) return Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double norm = 0;
  for (size_t i = 0; i < s.log_weight.size(); ++i) {
    const double wgt = static_cast<double>(std::exp(s.log_weight[i] - top)) * s.area[i];
    sum += wgt * s.colour[i]->cast<double>();
    norm += wgt;
  }
  // The bright pixels' excess, on the same weight scale, where it can matter.
  for (size_t b = 0; b < bright.dir.size(); ++b) {
    const float c = uf.dot(bright.dir[b]);
    if (c <= 0 || c < bright_cos) continue;
    sum += static_cast<double>(std::exp(log_weight(bright.dir[b]) - top)) * bright.area[b] * bright.excess[b].cast<double>();
    *samples += 1;
  }
  return (sum / norm).cast<float>();
}

}  // namespace

Eigen::Vector3d EnvironmentMap::voxel_centre(int i, int j, int k) const {
  return (Eigen::Vector3d(i, j, k).array() + 0.5).matrix() * (2.0 / size_) - Eigen::Vector3d::Ones();
}

Eigen::Vector3f EnvironmentMap::voxel(int i, int j, int k) const {
  const size_t v = (static_cast<size_t>(k) * size_ + j) * size_ + i;
  return {rgb_[3 * v], rgb_[3 * v + 1], rgb_[3 * v + 2]};
}

Eigen::Vector3f EnvironmentMap::lookup(const Eigen::Vector3d& t) const {
  const Eigen::Vector3d p = (t.array() + 1).matrix() * (size_ / 2.0) - Eigen::Vector3d::Constant(0.5);
  int i0[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    const double c = std::clamp(p[a], 0.0, size_ - 1.0);
    i0[a] = std::min(static_cast<int>(std::floor(c)), size_ - 2);
    f[a] = c - i0[a];
  }
  Eigen::Vector3f out = Eigen::Vector3f::Zero();
  for (int dz = 0; dz < 2; ++dz)
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const double w = (dx ? f[0] : 1 - f[0]) * (dy ? f[1] : 1 - f[1]) * (dz ? f[2] : 1 - f[2]);
        if (w > 0) out += static_cast<float>(w) * voxel(i0[0] + dx, i0[1] + dy, i0[2] + dz);
      }
  return out;
}

Eigen::Vector3f EnvironmentMap::reflect(const Eigen::Vector3d& r, double exponent) const {
  return lookup(r.normalized() * envmap_radius(exponent, size_, levels_));
}

Result<EnvironmentMap> build_envmap(const Panorama& pano, const EnvmapOptions& o, EnvmapStats* stats) {
  if (o.size < 2 || o.size > 1024) return fail(fmt::format("environment map size {} must be in 2..1024", o.size));
  if (!(o.intensity_levels > 1) || !std::isfinite(o.intensity_levels))
    return fail(fmt::format("intensity levels {} must be finite and > 1", o.intensity_levels));
  if (!(o.threshold > 0 && o.threshold < 1)) return fail(fmt::format("weight threshold {} must be in (0, 1)", o.threshold));
  if (!(o.samples_per_scale > 0) || !std::isfinite(o.samples_per_scale))
    return fail(fmt::format("samples per lobe scale {} must be finite and > 0", o.samples_per_scale));
  if (!(o.max_scale_rad > 0 && o.max_scale_rad <= M_PI)) return fail("the largest lobe scale must be in (0, pi]");
  Stopwatch clock;
  const Pyramid built = build_pyramid(pano);
  const std::vector<Level>& pyramid = built.levels;
  EnvmapStats st;
  st.pyramid_seconds = clock.seconds();
  st.voxels_per_level.assign(pyramid.size(), 0);

  // The mean over the whole sphere: the value at t = 0, where no direction is defined.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  double total = 0;
  for (int y = 0; y < pano.height(); ++y)
    for (int x = 0; x < pano.width(); ++x) {
      mean += pano.solid_angle(y) * pano.at(x, y).cast<double>();
      total += pano.solid_angle(y);
    }
  mean /= total;

  EnvironmentMap map;
  map.size_ = o.size;
  map.levels_ = o.intensity_levels;
  const int s = o.size;
  map.rgb_.assign(static_cast<size_t>(s) * s * s * 3, 0.f);
  const double margin = 1 + std::sqrt(3.0) * 2 / s;  // every voxel a trilinear lookup at |t| <= 1 reads
  const double log_th = std::log(o.threshold);

  std::mutex mutex;
  std::atomic<size_t> computed{0}, outside{0};
  std::vector<double> samples_per_slice(s, 0);
  std::vector<std::vector<size_t>> levels_per_slice(s, std::vector<size_t>(pyramid.size(), 0));
  std::atomic<int> failed_voxels{0};
  Progress progress("envmap", static_cast<size_t>(s));
  parallel_for(s, o.threads, [&](int k) {
    Scratch scratch;
    size_t here = 0, skipped = 0;
    for (int j = 0; j < s; ++j)
      for (int i = 0; i < s; ++i) {
        const Eigen::Vector3d t = map.voxel_centre(i, j, k);
        const double radius = t.norm();
        if (radius > margin) {
          ++skipped;
          continue;
        }
        Eigen::Vector3f value;
        if (radius == 0) {
          value = mean.cast<float>();
        } else {
          const Eigen::Vector3d u = t / radius;
          const double L = envmap_exponent(radius, s, o.intensity_levels);
          // The cap where (u.w)^L >= th: chord^2 = 2 (1 - cos) = -2 expm1(log th / L).
          double cap = M_PI / 2;
          if (L > 0) cap = std::min(cap, 2 * std::asin(std::min(1.0, 0.5 * std::sqrt(-2 * std::expm1(log_th / L)))));
          const double scale = L > 0 ? std::min(1 / std::sqrt(L), o.max_scale_rad) : o.max_scale_rad;
          size_t lv = 0;
          while (lv + 1 < pyramid.size() && pyramid[lv + 1].spacing <= scale / o.samples_per_scale) ++lv;
          ++levels_per_slice[k][lv];
          // Bright pixels count out to where weight x largest excess falls below
          // th x the panorama's brightness cut (relative to the peak weight).
          float bright_cos = -1;
          if (L > 0 && !built.bright.dir.empty()) {
            const double log_th_b = log_th - std::log(std::max(1.0, static_cast<double>(built.bright.largest_excess) / built.bright.level));
            bright_cos = static_cast<float>(std::exp(log_th_b / L));
          }
          value = lobe(pyramid[lv], built.bright, u, L, cap, bright_cos, scratch, &samples_per_slice[k]);
          if (!value.allFinite()) {
            ++failed_voxels;
            value = pano.lookup(u);
          }
        }
        const size_t v = (static_cast<size_t>(k) * s + j) * s + i;
        for (int c = 0; c < 3; ++c) map.rgb_[3 * v + c] = value[c];
        ++here;
      }
    computed += here;
    outside += skipped;
    std::lock_guard<std::mutex> lock(mutex);
    progress.tick();
  });
  progress.done();
  if (failed_voxels > 0) return fail(fmt::format("environment map: {} voxels found no panorama pixel in their cap (a bug)", failed_voxels.load()));
  st.voxels = computed;
  st.voxels_outside = outside;
  for (int k = 0; k < s; ++k) {
    st.samples += samples_per_slice[k];
    for (size_t l = 0; l < pyramid.size(); ++l) st.voxels_per_level[l] += levels_per_slice[k][l];
  }
  st.memory_bytes = map.rgb_.size() * sizeof(float);
  st.seconds = clock.seconds();
  if (stats) *stats = st;
  return map;
}

Status EnvironmentMap::save(const fs::path& path, const std::string& source) const {
  ImageF img(size_, size_ * size_, 3);
  img.data = rgb_;
  const float top = rgb_.empty() ? 0.f : *std::max_element(rgb_.begin(), rgb_.end());
  const bool half = top <= 65504.f;  // half's largest finite value
  ExrAttributes attrs{{"s2r:format", "envmap"},
                      {"s2r:version", std::to_string(kFormatVersion)},
                      {"s2r:size", std::to_string(size_)},
                      {"s2r:intensity_levels", fmt::format("{}", levels_)},
                      {"s2r:source", source}};
  return write_exr(path, img, attrs, half);
}

Result<EnvironmentMap> EnvironmentMap::load(const fs::path& path) {
  ExrAttributes attrs;
  auto img = read_exr(path, &attrs);
  if (!img) return std::unexpected(img.error());
  const std::string where = "'" + path.string() + "': ";
  const auto field = [&](const std::string& name) -> Result<std::string> {
    auto it = attrs.find(name);
    if (it == attrs.end()) return fail(where + "not an environment map: attribute " + name + " missing");
    return it->second;
  };
  auto format = field("s2r:format");
  if (!format) return std::unexpected(format.error());
  if (*format != "envmap") return fail(where + "s2r:format is '" + *format + "', not 'envmap'");
  auto version = field("s2r:version");
  if (!version) return std::unexpected(version.error());
  if (*version != std::to_string(kFormatVersion))
    return fail(where + "envmap version " + *version + " is not supported (this build reads " + std::to_string(kFormatVersion) + ")");
  auto size_s = field("s2r:size");
  auto levels_s = field("s2r:intensity_levels");
  if (!size_s) return std::unexpected(size_s.error());
  if (!levels_s) return std::unexpected(levels_s.error());
  EnvironmentMap map;
  try {
    size_t used = 0;
    map.size_ = std::stoi(*size_s, &used);
    if (used != size_s->size()) throw std::invalid_argument("trailing characters");
    map.levels_ = std::stod(*levels_s, &used);
    if (used != levels_s->size()) throw std::invalid_argument("trailing characters");
  } catch (const std::exception&) {
    return fail(where + "s2r:size '" + *size_s + "' or s2r:intensity_levels '" + *levels_s + "' is not a number");
  }
  if (map.size_ < 2 || map.size_ > 1024) return fail(where + "s2r:size " + *size_s + " must be in 2..1024");
  if (!(map.levels_ > 1) || !std::isfinite(map.levels_)) return fail(where + "s2r:intensity_levels must be > 1");
  if (img->channels != 3 || img->width != map.size_ || img->height != map.size_ * map.size_)
    return fail(where + fmt::format("image is {}x{}x{}: an envmap of size {} is {}x{}x3", img->width, img->height,
                                    img->channels, map.size_, map.size_, map.size_ * map.size_));
  for (size_t i = 0; i < img->data.size(); ++i)
    if (!std::isfinite(img->data[i]) || img->data[i] < 0)
      return fail(where + fmt::format("voxel {} holds {}: values must be finite and >= 0", i / 3, img->data[i]));
  map.rgb_ = std::move(img->data);
  return map;
}

Result<Panorama> load_panorama(const fs::path& path, bool clamp, std::vector<std::string>* warnings) {
  auto img = read_image_float(path);
  if (!img) return std::unexpected(img.error());
  if (clamp) {
    float largest = 0;
    for (float v : img->data)
      if (std::isfinite(v)) largest = std::max(largest, v);
    size_t nan = 0, inf = 0, negative = 0;
    for (float& v : img->data) {
      if (std::isnan(v)) ++nan, v = 0;
      else if (std::isinf(v)) ++inf, v = v > 0 ? largest : 0;
      else if (v < 0) ++negative, v = 0;
    }
    if ((nan || inf || negative) && warnings)
      warnings->push_back(fmt::format("'{}': clamped {} NaN, {} infinite and {} negative values (NaN and negative to 0, "
                                      "+Inf to the largest finite value {})",
                                      path.string(), nan, inf, negative, largest));
  }
  auto pano = Panorama::create(std::move(*img));
  if (!pano) return fail("'" + path.string() + "': " + pano.error().message + (clamp ? "" : " (clamping replaces such values)"));
  return pano;
}

}  // namespace s2r
