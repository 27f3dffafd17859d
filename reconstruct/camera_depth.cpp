#include "reconstruct/camera_depth.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <numbers>
#include <thread>

#include <embree3/rtcore.h>
#include <emmintrin.h>

#include "core/parallel.h"

namespace s2r {

struct MeshRaycaster::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  size_t triangles = 0;
  // The mesh's bounds, a little enlarged: rays that miss them are not traced
  // (most of a turntable camera's pixels see no object).
  Eigen::AlignedBox3f bounds;
  std::mutex rays_mutex;
  std::shared_ptr<const std::vector<Eigen::Vector3f>> rays;
  Intrinsics rays_for;
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

MeshRaycaster::MeshRaycaster(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MeshRaycaster::~MeshRaycaster() = default;
size_t MeshRaycaster::triangles() const { return impl_->triangles; }

Result<std::unique_ptr<MeshRaycaster>> MeshRaycaster::create(const Mesh& mesh) {
  auto impl = std::make_unique<Impl>();
  impl->device = rtcNewDevice(nullptr);
  if (!impl->device) return fail("Embree: cannot create a device (error " + std::to_string(rtcGetDeviceError(nullptr)) + ")");
  impl->scene = rtcNewScene(impl->device);
  if (!mesh.faces.empty()) {
    RTCGeometry g = rtcNewGeometry(impl->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                           3 * sizeof(float), mesh.vertices.size()));
    auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                              3 * sizeof(unsigned), mesh.faces.size()));
    if (!vb || !ib) {
      rtcReleaseGeometry(g);
      return fail("Embree: out of memory for " + std::to_string(mesh.faces.size()) + " triangles");
    }
    for (size_t i = 0; i < mesh.vertices.size(); ++i) {
      for (int k = 0; k < 3; ++k) vb[3 * i + k] = mesh.vertices[i][k];
      impl->bounds.extend(Eigen::Vector3f(vb[3 * i], vb[3 * i + 1], vb[3 * i + 2]));
    }
    const float pad = 1e-4f * impl->bounds.diagonal().norm() + 1e-6f;
    impl->bounds.min().array() -= pad;
    impl->bounds.max().array() += pad;
    for (size_t i = 0; i < mesh.faces.size(); ++i)
      for (int k = 0; k < 3; ++k) ib[3 * i + k] = static_cast<unsigned>(mesh.faces[i][k]);
    rtcCommitGeometry(g);
    rtcAttachGeometry(impl->scene, g);
    rtcReleaseGeometry(g);
    impl->triangles = mesh.faces.size();
  }
  rtcCommitScene(impl->scene);
  if (rtcGetDeviceError(impl->device) != RTC_ERROR_NONE) return fail("Embree: scene build failed");
  return std::unique_ptr<MeshRaycaster>(new MeshRaycaster(std::move(impl)));
}

namespace {

// Whether the ray o + t d (t >= 0) meets the box (slabs; IEEE infinities
// handle axis-parallel rays, NaN comparisons fail towards "meets").
bool meets(const Eigen::AlignedBox3f& b, const Eigen::Vector3f& o, const Eigen::Vector3f& d) {
  if (b.isEmpty()) return false;
  float t0 = 0, t1 = std::numeric_limits<float>::infinity();
  for (int k = 0; k < 3; ++k) {
    const float inv = 1.f / d[k];
    float a = (b.min()[k] - o[k]) * inv, c = (b.max()[k] - o[k]) * inv;
    if (a > c) std::swap(a, c);
    if (a > t0) t0 = a;
    if (c < t1) t1 = c;
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace

float MeshRaycaster::distance(const Eigen::Vector3f& o, const Eigen::Vector3f& d) const {
  if (!meets(impl_->bounds, o, d)) return 0.f;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh{};
  rh.ray.org_x = o.x(), rh.ray.org_y = o.y(), rh.ray.org_z = o.z();
  rh.ray.dir_x = d.x(), rh.ray.dir_y = d.y(), rh.ray.dir_z = d.z();
  rh.ray.tnear = 0;
  rh.ray.tfar = std::numeric_limits<float>::infinity();
  rh.ray.mask = 0xffffffffu;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->scene, &ctx, &rh);
  return rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? 0.f : rh.ray.tfar;
}

// Undistorting every pixel is the costly part: the rays of the last
// intrinsics are kept (the cameras of a session share them).
std::shared_ptr<const std::vector<Eigen::Vector3f>> MeshRaycaster::rays_of(const Intrinsics& K, int threads) const {
  std::lock_guard<std::mutex> lock(impl_->rays_mutex);
  if (!impl_->rays || !(impl_->rays_for.K() == K.K()) || impl_->rays_for.dist != K.dist ||
      impl_->rays_for.width != K.width || impl_->rays_for.height != K.height) {
    auto r = std::make_shared<std::vector<Eigen::Vector3f>>();
    r->assign(size_t(K.width) * K.height, Eigen::Vector3f::Zero());
    parallel_for(K.height, worker_count(threads), [&](int y) {
      for (int x = 0; x < K.width; ++x)
        if (auto ray = K.ray({double(x), double(y)})) (*r)[size_t(y) * K.width + x] = ray->cast<float>().normalized();
    });
    impl_->rays = r;
    impl_->rays_for = K;
  }
  return impl_->rays;
}

ImageF MeshRaycaster::distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, int threads) const {
  ImageF out(K.width, K.height, 1, 0.f);
  const Eigen::Matrix3f R = world_from_camera.linear().cast<float>();
  const Eigen::Vector3f o = world_from_camera.translation().cast<float>();
  const std::shared_ptr<const std::vector<Eigen::Vector3f>> rays = rays_of(K, threads);
  // Eight pixels of a row at a time, of those whose rays meet the mesh's
  // bounds: neighbouring rays traced as one packet.
  parallel_for(K.height, worker_count(threads), [&](int y) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    alignas(32) int valid[8];
    alignas(32) RTCRayHit8 rh;
    int xs[8];
    int lanes = 0;
    auto trace = [&] {
      for (int k = lanes; k < 8; ++k) valid[k] = 0;
      rtcIntersect8(valid, impl_->scene, &ctx, &rh);
      for (int k = 0; k < lanes; ++k)
        if (rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID) out.data[size_t(y) * K.width + xs[k]] = rh.ray.tfar[k];
      lanes = 0;
    };
    for (int x = 0; x < K.width; ++x) {
      const Eigen::Vector3f& r = (*rays)[size_t(y) * K.width + x];
      if (r.z() <= 0) continue;
      const Eigen::Vector3f d = R * r;
      if (!meets(impl_->bounds, o, d)) continue;
      const int k = lanes++;
      xs[k] = x;
      valid[k] = -1;
      rh.ray.org_x[k] = o.x(), rh.ray.org_y[k] = o.y(), rh.ray.org_z[k] = o.z();
      rh.ray.dir_x[k] = d.x(), rh.ray.dir_y[k] = d.y(), rh.ray.dir_z[k] = d.z();
      rh.ray.tnear[k] = 0;
      rh.ray.tfar[k] = std::numeric_limits<float>::infinity();
      rh.ray.time[k] = 0;
      rh.ray.mask[k] = 0xffffffffu;
      rh.ray.id[k] = 0;
      rh.ray.flags[k] = 0;
      rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
      if (lanes == 8) trace();
    }
    if (lanes) trace();
  });
  return out;
}

// --- Rasterizer ------------------------------------------------------------

namespace {

// A camera's pixel rays and where its lens model can be inverted: rays are
// normalised coordinates (x/z, y/z) of the pixel centres (NaN where
// undistortion fails) with their length |(x/z, y/z, 1)| apart, the
// window bounds the rays' normalised coordinates (x/z, y/z), and within
// radius `valid_r` (normalised) the radial distortion is monotonic, so a
// vertex there projects to one place.
//
// Undistorting a pixel takes Newton's iterations: the rays are made tile by
// tile when a triangle first needs them (most of a turntable camera's pixels
// never see the object), once, by whichever thread comes first.
struct PixelRays {
  static constexpr int kTile = 16;  // pixels a side
  Intrinsics K;
  // Rays as separate x and y rows (a row of pixels reads two contiguous runs).
  mutable std::vector<float> ray_x, ray_y;
  mutable std::vector<float> length;
  float x0 = 0, x1 = 0, y0 = 0, y1 = 0;  // normalised window of the image, a little enlarged
  float valid_r2 = std::numeric_limits<float>::infinity();
  // How far the lens bows a straight edge: a chord of L pixels strays at
  // most bow L^2 pixels from the projected edge (max |P''| / (8 m^2) over the
  // window, P the lens map, m its smallest scale). 0 for a pinhole.
  float bow = 0;
  int tiles_x = 0, tiles_y = 0;
  // Per tile: 0 not made, 1 being made, 2 made (release / acquire).
  std::unique_ptr<std::atomic<uint8_t>[]> tile_state;
  mutable std::atomic<size_t> tiles_made{0};

  // The rays of pixels [xa, xb] x [ya, yb] (within the image) are ready on return.
  void need(int xa, int xb, int ya, int yb) const {
    for (int ty = ya / kTile; ty <= yb / kTile; ++ty)
      for (int tx = xa / kTile; tx <= xb / kTile; ++tx) {
        std::atomic<uint8_t>& state = tile_state[size_t(ty) * size_t(tiles_x) + size_t(tx)];
        if (state.load(std::memory_order_acquire) == 2) continue;
        uint8_t expected = 0;
        if (state.compare_exchange_strong(expected, 1, std::memory_order_acq_rel)) {
          make_tile(tx, ty);
          tiles_made.fetch_add(1, std::memory_order_relaxed);
          state.store(2, std::memory_order_release);
        } else {
          while (state.load(std::memory_order_acquire) != 2) std::this_thread::yield();
        }
      }
  }

  // Each pixel's undistortion starts from its left neighbours' answers
  // extrapolated (two Newton steps then usually suffice).
  void make_tile(int tx, int ty) const {
    const int xa = tx * kTile, xb = std::min(K.width, xa + kTile);
    const int ya = ty * kTile, yb = std::min(K.height, ya + kTile);
    const Eigen::Vector2d none = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
    for (int y = ya; y < yb; ++y) {
      Eigen::Vector2d p1 = none, p2 = none;
      for (int x = xa; x < xb; ++x) {
        const Eigen::Vector2d xd((x - K.cx) / K.fx, (y - K.cy) / K.fy);
        const Eigen::Vector2d start = p2.allFinite() ? Eigen::Vector2d(2 * p1 - p2) : p1;
        const auto xn = K.undistort(xd, start);
        p2 = p1;
        p1 = xn && xn->allFinite() ? *xn : none;
        if (!p1.allFinite()) continue;
        ray_x[size_t(y) * K.width + x] = float(p1.x());
        ray_y[size_t(y) * K.width + x] = float(p1.y());
        length[size_t(y) * K.width + x] = float(std::sqrt(p1.squaredNorm() + 1.0));
      }
    }
  }
};

std::shared_ptr<const PixelRays> make_pixel_rays(const Intrinsics& K, int threads) {
  auto pr = std::make_shared<PixelRays>();
  pr->K = K;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  pr->ray_x.assign(size_t(K.width) * K.height, nan);
  pr->ray_y.assign(size_t(K.width) * K.height, nan);
  pr->length.assign(size_t(K.width) * K.height, 0.f);
  pr->tiles_x = (std::max(K.width, 0) + PixelRays::kTile - 1) / PixelRays::kTile;
  pr->tiles_y = (std::max(K.height, 0) + PixelRays::kTile - 1) / PixelRays::kTile;
  pr->tile_state = std::make_unique<std::atomic<uint8_t>[]>(size_t(pr->tiles_x) * size_t(pr->tiles_y));
  // The window from the image's border: the lens map is one to one, so its
  // image of the rectangle is bounded by its image of the border, where
  // x, y and r^2 (convex) take their extremes. Where a border pixel cannot be
  // undistorted every pixel is made now and the window taken over all.
  std::vector<Eigen::Vector2i> border;
  for (int x = 0; x < K.width; ++x) border.push_back({x, 0}), border.push_back({x, K.height - 1});
  for (int y = 1; y + 1 < K.height; ++y) border.push_back({0, y}), border.push_back({K.width - 1, y});
  float x0 = std::numeric_limits<float>::infinity(), x1 = -x0, y0 = x0, y1 = -x0, r2max = 0;
  bool border_ok = true;
  auto extend = [&](const Eigen::Vector2d& xn) {
    const float xu = float(xn.x()), yu = float(xn.y());
    x0 = std::min(x0, xu), x1 = std::max(x1, xu), y0 = std::min(y0, yu), y1 = std::max(y1, yu);
    r2max = std::max(r2max, xu * xu + yu * yu);
  };
  for (const Eigen::Vector2i& b : border) {
    const auto xn = K.undistort(Eigen::Vector2d((b.x() - K.cx) / K.fx, (b.y() - K.cy) / K.fy));
    if (!xn || !xn->allFinite()) {
      border_ok = false;
      break;
    }
    extend(*xn);
  }
  if (!border_ok) {
    x0 = std::numeric_limits<float>::infinity(), x1 = -x0, y0 = x0, y1 = -x0, r2max = 0;
    parallel_for(pr->tiles_y, worker_count(threads), [&](int ty) { pr->need(0, K.width - 1, ty * PixelRays::kTile, ty * PixelRays::kTile); });
    for (size_t p = 0; p < pr->ray_x.size(); ++p)
      if (std::isfinite(pr->ray_x[p]) && std::isfinite(pr->ray_y[p])) extend(Eigen::Vector2d(pr->ray_x[p], pr->ray_y[p]));
  }
  const float mx = 2.f / float(K.fx), my = 2.f / float(K.fy);  // two pixels of margin
  pr->x0 = x0 - mx, pr->x1 = x1 + mx, pr->y0 = y0 - my, pr->y1 = y1 + my;
  if (K.has_distortion()) {
    // The first radius (up to four times the image's) where r (1 + k1 r^2 +
    // k2 r^4 + k3 r^6) stops growing; at least the image's own.
    const double k1 = K.dist[0], k2 = K.dist[1], k3 = K.dist[4];
    const double rmax = std::sqrt(double(r2max)), limit = 4 * rmax;
    double valid = limit;
    for (double r = 0; r <= limit; r += limit / 4000) {
      const double r2 = r * r;
      if (1 + r2 * (3 * k1 + r2 * (5 * k2 + 7 * k3 * r2)) <= 0) {
        valid = r;
        break;
      }
    }
    // The window's corners too: clipped triangles are projected up to them.
    const double corner = std::sqrt(std::max(double(pr->x0) * pr->x0, double(pr->x1) * pr->x1) +
                                    std::max(double(pr->y0) * pr->y0, double(pr->y1) * pr->y1));
    valid = std::max(valid, corner * 1.01);
    pr->valid_r2 = float(valid * valid);
    // The bow, by finite differences on a grid over the window (and a
    // factor of 1.5 for what the grid misses).
    auto P = [&](double x, double y) {
      const Eigen::Vector2d d = K.distort(Eigen::Vector2d(x, y));
      return std::array<double, 2>{K.fx * d.x(), K.fy * d.y()};
    };
    const double h = 1e-3;
    double second = 0, scale = std::numeric_limits<double>::infinity();
    for (int i = 0; i <= 32; ++i)
      for (int j = 0; j <= 32; ++j) {
        const double qx = pr->x0 + (pr->x1 - pr->x0) * i / 32.0, qy = pr->y0 + (pr->y1 - pr->y0) * j / 32.0;
        const auto c = P(qx, qy), xp = P(qx + h, qy), xm = P(qx - h, qy), yp = P(qx, qy + h), ym = P(qx, qy - h);
        // The Jacobian's smallest singular value (closed form for 2 x 2).
        const double a = (xp[0] - xm[0]) / (2 * h), b = (yp[0] - ym[0]) / (2 * h);
        const double cc = (xp[1] - xm[1]) / (2 * h), d = (yp[1] - ym[1]) / (2 * h);
        const double t = a * a + b * b + cc * cc + d * d, det = a * d - b * cc;
        scale = std::min(scale, std::sqrt(std::max(0.0, (t - std::sqrt(std::max(0.0, t * t - 4 * det * det))) / 2)));
        for (int k = 0; k < 4; ++k) {
          const double dx = h * std::cos(k * std::numbers::pi / 4), dy = h * std::sin(k * std::numbers::pi / 4);
          const auto p = P(qx + dx, qy + dy), m = P(qx - dx, qy - dy);
          second = std::max(second, std::hypot(p[0] + m[0] - 2 * c[0], p[1] + m[1] - 2 * c[1]) / (h * h));
        }
      }
    pr->bow = scale > 0 ? float(1.5 * second / (8 * scale * scale)) : std::numeric_limits<float>::infinity();
  }
  return pr;
}

// The exact cone test of one triangle (camera frame, camera at the origin): a
// ray u = (x/z, y/z, 1) meets it (in front) when s e[k].u >= 0 for all k,
// with e[k] the plane through the origin and the edge opposite vertex k and s
// the sign of det(a, b, c). Its inverse depth is then 1/z = m.u for the
// triangle's plane m.p = 1 (m = n / (n.a), n its normal; the distance along
// the ray is z |u|): well conditioned where the barycentric sums are not (the
// e[k] are nearly perpendicular to the rays, and their dot products cancel).
struct TriangleTest {
  Eigen::Vector3f e[3];
  Eigen::Vector3f m;
};

class Raster {
 public:
  Raster(const PixelRays& pr, ImageF& depth, MeshRasterizer::Stats& st) : pr_(pr), K_(pr.K), depth_(depth), st_(st) {
    distorted_ = K_.has_distortion();
    for (int k = 0; k < 5; ++k) dist_[k] = float(K_.dist[size_t(k)]);
  }

  // Normalised (x/z, y/z) -> pixel through the lens model (float).
  Eigen::Vector2f pixel(float xn, float yn) const {
    __m128 px, py;
    lens4(_mm_set1_ps(xn), _mm_set1_ps(yn), px, py);
    return {_mm_cvtss_f32(px), _mm_cvtss_f32(py)};
  }
  // Four camera-frame points' pixels, NaN where a point does not project
  // (within kNear of the camera plane or beyond the lens model's valid field).
  void pixels4(__m128 x, __m128 y, __m128 z, __m128& px, __m128& py) const {
    const __m128 xn = _mm_div_ps(x, z), yn = _mm_div_ps(y, z);
    const __m128 r2 = _mm_add_ps(_mm_mul_ps(xn, xn), _mm_mul_ps(yn, yn));
    const __m128 ok = _mm_and_ps(_mm_cmpgt_ps(z, _mm_set1_ps(kNear)), _mm_cmple_ps(r2, _mm_set1_ps(pr_.valid_r2)));
    lens4(xn, yn, px, py);
    const __m128 nan = _mm_set1_ps(std::numeric_limits<float>::quiet_NaN());
    px = _mm_or_ps(_mm_and_ps(ok, px), _mm_andnot_ps(ok, nan));
    py = _mm_or_ps(_mm_and_ps(ok, py), _mm_andnot_ps(ok, nan));
  }

  // The triangle's pixels when its vertices alone do not bound them (behind
  // the camera, beyond the lens model's field, or wide under distortion): the
  // triangle clipped to the view's frustum (near plane and the image's
  // normalised window), its edges sampled through the lens every few pixels.
  void clipped(const TriangleTest& t, const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
    std::vector<Eigen::Vector3f> poly{a, b, c}, next;
    // Planes as (x, y, z) coefficients: inside where n.p >= offset (near plane only).
    const Eigen::Vector3f planes[5] = {{0, 0, 1}, {1, 0, -pr_.x0}, {-1, 0, pr_.x1}, {0, 1, -pr_.y0}, {0, -1, pr_.y1}};
    for (int k = 0; k < 5 && !poly.empty(); ++k) {
      const float off = k == 0 ? kNear : 0.f;
      next.clear();
      for (size_t i = 0; i < poly.size(); ++i) {
        const Eigen::Vector3f &p = poly[i], &q = poly[(i + 1) % poly.size()];
        const float dp = planes[k].dot(p) - off, dq = planes[k].dot(q) - off;
        if (dp >= 0) next.push_back(p);
        if ((dp >= 0) != (dq >= 0)) next.push_back(p + (q - p) * (dp / (dp - dq)));
      }
      poly.swap(next);
    }
    if (poly.empty()) {
      ++st_.triangles_culled;
      return;
    }
    Eigen::Vector2f lo = Eigen::Vector2f::Constant(std::numeric_limits<float>::infinity()), hi = -lo;
    auto add = [&](const Eigen::Vector3f& p) {
      const float z = std::max(p.z(), kNear);
      const Eigen::Vector2f q = pixel(p.x() / z, p.y() / z);
      lo = lo.cwiseMin(q), hi = hi.cwiseMax(q);
    };
    float longest = 0;
    for (size_t i = 0; i < poly.size(); ++i) {
      const Eigen::Vector3f &p = poly[i], &q = poly[(i + 1) % poly.size()];
      int n = 1;
      if (distorted_) {
        const float zp = std::max(p.z(), kNear), zq = std::max(q.z(), kNear);
        const float len = (pixel(p.x() / zp, p.y() / zp) - pixel(q.x() / zq, q.y() / zq)).norm();
        n = std::clamp(int(std::ceil(len / 8)), 1, 256);
        longest = std::max(longest, len / float(n));
      }
      for (int j = 0; j < n; ++j) add(p + (q - p) * (float(j) / float(n)));
    }
    // Edges sampled every 8 pixels or closer (at most 256 samples, past which the
    // pad grows with the longest piece).
    pixels(t, lo, hi, kRound + pr_.bow * longest * longest);
  }

  // Tests the pixels whose centres lie within `pad` of [lo, hi].
  void pixels(const TriangleTest& t, const Eigen::Vector2f& lo, const Eigen::Vector2f& hi, float pad) {
    // Clamped to the image before any conversion to int (no overflow, no NaN).
    const float W = float(K_.width), H = float(K_.height);
    if (!(lo.x() - pad <= W && lo.y() - pad <= H && hi.x() + pad >= -1.f && hi.y() + pad >= -1.f)) {
      ++st_.triangles_culled;
      return;
    }
    // Ceiling and floor through truncation (SSE2 has no rounding
    // instruction; the values lie within [-1, W] and [-1, H]).
    auto ceil_of = [](float v) { const int i = int(v); return i + (float(i) < v); };
    auto floor_of = [](float v) { const int i = int(v); return i - (float(i) > v); };
    const int xa = ceil_of(std::max(lo.x() - pad, 0.f)), xb = floor_of(std::min(hi.x() + pad, W - 1));
    const int ya = ceil_of(std::max(lo.y() - pad, 0.f)), yb = floor_of(std::min(hi.y() + pad, H - 1));
    if (xa > xb || ya > yb) {
      ++st_.triangles_culled;
      return;
    }
    ++st_.triangles_drawn;
    st_.pixels_tested += size_t(xb - xa + 1) * size_t(yb - ya + 1);
    pr_.need(xa, xb, ya, yb);
    drawn_x0_ = std::min(drawn_x0_, xa), drawn_x1_ = std::max(drawn_x1_, xb);
    drawn_y0_ = std::min(drawn_y0_, ya), drawn_y1_ = std::max(drawn_y1_, yb);
    const float e0x = t.e[0].x(), e0y = t.e[0].y(), e0z = t.e[0].z();
    const float e1x = t.e[1].x(), e1y = t.e[1].y(), e1z = t.e[1].z();
    const float e2x = t.e[2].x(), e2y = t.e[2].y(), e2z = t.e[2].z();
    // The buffer holds inverse depth 1/z = m.u: products per pixel, no
    // quotient, and 0 (no surface) is the farthest value.
    const float nx = t.m.x(), ny = t.m.y(), nz = t.m.z();
    // Four pixels of a row at a time, branch-free (rows are short: a
    // triangle covers a few pixels, where mispredicted branches cost more
    // than the tests): a pixel the triangle does not take keeps its value
    // through max(). NaN rays fail every comparison; nearer than the buffer
    // implies in front (> 0). Lanes past the row's end are masked off: they
    // read the next row's rays and values and write back what they read
    // (one thread draws an image), except at the image's very end.
    const __m128 E0x = _mm_set1_ps(e0x), E0y = _mm_set1_ps(e0y), E0z = _mm_set1_ps(e0z);
    const __m128 E1x = _mm_set1_ps(e1x), E1y = _mm_set1_ps(e1y), E1z = _mm_set1_ps(e1z);
    const __m128 E2x = _mm_set1_ps(e2x), E2y = _mm_set1_ps(e2y), E2z = _mm_set1_ps(e2z);
    const __m128 Nx = _mm_set1_ps(nx), Ny = _mm_set1_ps(ny), Nz = _mm_set1_ps(nz), zero = _mm_setzero_ps();
    const __m128i lane = _mm_setr_epi32(0, 1, 2, 3);
    const size_t end = depth_.data.size();
    for (int y = ya; y <= yb; ++y) {
      const size_t row = size_t(y) * size_t(K_.width);
      const float* rx = pr_.ray_x.data() + row;
      const float* ry = pr_.ray_y.data() + row;
      float* inv = depth_.data.data() + row;
      for (int x = xa; x <= xb; x += 4) {
        if (row + size_t(x) + 4 > end) {  // the image's last pixels, one at a time
          for (; x <= xb; ++x) {
            const float ux = rx[x], uy = ry[x], w = nx * ux + ny * uy + nz;
            if ((e0x * ux + e0y * uy + e0z >= 0) && (e1x * ux + e1y * uy + e1z >= 0) && (e2x * ux + e2y * uy + e2z >= 0) &&
                w > inv[x])
              inv[x] = w;
          }
          break;
        }
        const __m128 ux = _mm_loadu_ps(rx + x), uy = _mm_loadu_ps(ry + x), z = _mm_loadu_ps(inv + x);
        const __m128 w = _mm_add_ps(_mm_add_ps(_mm_mul_ps(Nx, ux), _mm_mul_ps(Ny, uy)), Nz);
        const __m128 a = _mm_add_ps(_mm_add_ps(_mm_mul_ps(E0x, ux), _mm_mul_ps(E0y, uy)), E0z);
        const __m128 b = _mm_add_ps(_mm_add_ps(_mm_mul_ps(E1x, ux), _mm_mul_ps(E1y, uy)), E1z);
        const __m128 c = _mm_add_ps(_mm_add_ps(_mm_mul_ps(E2x, ux), _mm_mul_ps(E2y, uy)), E2z);
        const __m128 in_row = _mm_castsi128_ps(_mm_cmplt_epi32(lane, _mm_set1_epi32(xb - x + 1)));
        const __m128 take = _mm_and_ps(_mm_and_ps(_mm_and_ps(_mm_cmpge_ps(a, zero), _mm_cmpge_ps(b, zero)),
                                                  _mm_and_ps(_mm_cmpge_ps(c, zero), _mm_cmpgt_ps(w, z))),
                                       in_row);
        _mm_storeu_ps(inv + x, _mm_max_ps(z, _mm_and_ps(take, w)));
      }
    }
  }
  // The pixels tested so far lie in [x0, x1] x [y0, y1] (empty: x0 > x1).
  int drawn_x0() const { return drawn_x0_; }
  int drawn_x1() const { return drawn_x1_; }
  int drawn_y0() const { return drawn_y0_; }
  int drawn_y1() const { return drawn_y1_; }

 private:
  static constexpr float kNear = 1e-6f;   // metres in front of the centre

 public:
  static constexpr float kRound = 1e-3f;  // pixels: what float rounding may move a projected vertex
  float bow() const { return pr_.bow; }

 private:

  // The lens model on four normalised points (x/z, y/z) at once: Brown-
  // Conrady distortion (Intrinsics::distort's terms, in float), then the
  // focal lengths and principal point.
  void lens4(__m128 xn, __m128 yn, __m128& px, __m128& py) const {
    __m128 u = xn, v = yn;
    if (distorted_) {
      auto c = [](float f) { return _mm_set1_ps(f); };
      const __m128 r2 = _mm_add_ps(_mm_mul_ps(xn, xn), _mm_mul_ps(yn, yn));
      const __m128 radial = _mm_add_ps(
          c(1.f), _mm_mul_ps(r2, _mm_add_ps(c(dist_[0]), _mm_mul_ps(r2, _mm_add_ps(c(dist_[1]), _mm_mul_ps(r2, c(dist_[4])))))));
      const __m128 two = c(2.f);
      u = _mm_add_ps(_mm_add_ps(_mm_mul_ps(xn, radial), _mm_mul_ps(_mm_mul_ps(c(2 * dist_[2]), xn), yn)),
                     _mm_mul_ps(c(dist_[3]), _mm_add_ps(r2, _mm_mul_ps(_mm_mul_ps(two, xn), xn))));
      v = _mm_add_ps(_mm_add_ps(_mm_mul_ps(yn, radial), _mm_mul_ps(c(dist_[2]), _mm_add_ps(r2, _mm_mul_ps(_mm_mul_ps(two, yn), yn)))),
                     _mm_mul_ps(_mm_mul_ps(c(2 * dist_[3]), xn), yn));
    }
    px = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(float(K_.fx)), u), _mm_set1_ps(float(K_.cx)));
    py = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(float(K_.fy)), v), _mm_set1_ps(float(K_.cy)));
  }

  const PixelRays& pr_;
  const Intrinsics& K_;
  ImageF& depth_;
  MeshRasterizer::Stats& st_;
  bool distorted_ = false;
  float dist_[5];
  int drawn_x0_ = std::numeric_limits<int>::max(), drawn_x1_ = -1;
  int drawn_y0_ = std::numeric_limits<int>::max(), drawn_y1_ = -1;
};

}  // namespace

struct MeshRasterizer::Impl {
  // The mesh reordered for locality: faces along a Morton curve of their
  // centres, vertices numbered as the faces first use them (each camera
  // walks every face once, and their vertices are then mostly in cache).
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3i> faces;
  Faces faces_seen = Faces::kBoth;
  // Runs of kCluster consecutive faces (neighbours on the Morton curve) with
  // a sphere holding their vertices and a cone holding their unit normals
  // ((b - a) x (c - a), the inward winding's): a camera that sees every
  // normal of a run turned away from it skips the run's faces without a
  // test per face (Faces::kInwardWound only).
  static constexpr size_t kCluster = 16;
  struct Cluster {
    Eigen::Vector3d centre, axis;
    double radius = 0, cos_a = 0, sin_a = 1;
    bool cone = false;  // false: the normals span a half-space or more
  };
  std::vector<Cluster> clusters;
  std::mutex rays_mutex;
  std::vector<std::shared_ptr<const PixelRays>> rays;  // one per intrinsics seen
};

MeshRasterizer::MeshRasterizer(const Mesh& mesh, Faces faces) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.faces_seen = faces;
  const int nv = int(mesh.vertices.size());
  Eigen::AlignedBox3f box;
  for (const auto& v : mesh.vertices) box.extend(v);
  const Eigen::Vector3f lo = box.isEmpty() ? Eigen::Vector3f::Zero() : box.min();
  const Eigen::Vector3f scale =
      box.isEmpty() ? Eigen::Vector3f::Ones() : Eigen::Vector3f(1023.f / box.sizes().cwiseMax(1e-12f).array()).eval();
  auto spread = [](uint32_t x) {  // 10 bits to every third of 30
    x &= 0x3ff;
    x = (x | x << 16) & 0x030000ff, x = (x | x << 8) & 0x0300f00f;
    x = (x | x << 4) & 0x030c30c3, x = (x | x << 2) & 0x09249249;
    return x;
  };
  std::vector<std::pair<uint32_t, uint32_t>> order;  // (Morton code, face)
  order.reserve(mesh.faces.size());
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const Eigen::Vector3i& v = mesh.faces[f];
    bool ok = true;
    for (int k = 0; k < 3; ++k) ok = ok && v[k] >= 0 && v[k] < nv;
    if (!ok) continue;  // a face naming no vertex is no triangle
    const Eigen::Vector3f c = (mesh.vertices[size_t(v[0])] + mesh.vertices[size_t(v[1])] + mesh.vertices[size_t(v[2])]) / 3;
    const Eigen::Vector3f q = (c - lo).cwiseProduct(scale).cwiseMax(0.f).cwiseMin(1023.f);
    order.push_back({spread(uint32_t(q.x())) | spread(uint32_t(q.y())) << 1 | spread(uint32_t(q.z())) << 2, uint32_t(f)});
  }
  std::sort(order.begin(), order.end());
  std::vector<int> renumber(mesh.vertices.size(), -1);
  m.faces.reserve(order.size());
  for (const auto& [code, f] : order) {
    Eigen::Vector3i face;
    for (int k = 0; k < 3; ++k) {
      int& r = renumber[size_t(mesh.faces[f][k])];
      if (r < 0) r = int(m.vertices.size()), m.vertices.push_back(mesh.vertices[size_t(mesh.faces[f][k])]);
      face[k] = r;
    }
    m.faces.push_back(face);
  }
  if (faces != Faces::kInwardWound) return;
  std::vector<Eigen::Vector3d> normals;
  for (size_t first = 0; first < m.faces.size(); first += Impl::kCluster) {
    const size_t last = std::min(m.faces.size(), first + Impl::kCluster);
    Impl::Cluster c;
    Eigen::AlignedBox3d box;
    normals.clear();
    for (size_t f = first; f < last; ++f) {
      const Eigen::Vector3d a = m.vertices[size_t(m.faces[f][0])].cast<double>();
      const Eigen::Vector3d b = m.vertices[size_t(m.faces[f][1])].cast<double>();
      const Eigen::Vector3d cc = m.vertices[size_t(m.faces[f][2])].cast<double>();
      box.extend(a), box.extend(b), box.extend(cc);
      const Eigen::Vector3d n = (b - a).cross(cc - a);
      // A face without area has no normal; it covers no pixel either way.
      if (n.norm() > 0 && n.allFinite()) normals.push_back(n.normalized());
    }
    c.centre = box.center();
    for (size_t f = first; f < last; ++f)
      for (int k = 0; k < 3; ++k)
        c.radius = std::max(c.radius, (m.vertices[size_t(m.faces[f][k])].cast<double>() - c.centre).norm());
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const auto& n : normals) sum += n;
    if (sum.norm() > 1e-9 && sum.allFinite() && box.sizes().allFinite()) {
      c.axis = sum.normalized();
      c.cos_a = 1;
      for (const auto& n : normals) c.cos_a = std::min(c.cos_a, n.dot(c.axis));
      c.cos_a -= 1e-6;  // what rounding may hide of the widest angle
      if (c.cos_a > 0) c.cone = true, c.sin_a = std::sqrt(1 - c.cos_a * c.cos_a);
    }
    m.clusters.push_back(c);
  }
}

MeshRasterizer::~MeshRasterizer() = default;
size_t MeshRasterizer::triangles() const { return impl_->faces.size(); }

void MeshRasterizer::prepare(const Intrinsics& K, int threads) const { rays_of(K, threads); }

MeshRasterizer::RayTiles MeshRasterizer::ray_tiles() const {
  std::lock_guard<std::mutex> lock(impl_->rays_mutex);
  RayTiles t;
  for (const auto& r : impl_->rays)
    t.made += r->tiles_made.load(std::memory_order_relaxed), t.total += size_t(r->tiles_x) * size_t(r->tiles_y);
  return t;
}

std::shared_ptr<const void> MeshRasterizer::rays_of(const Intrinsics& K, int threads) const {
  std::lock_guard<std::mutex> lock(impl_->rays_mutex);
  for (const auto& r : impl_->rays)
    if (r->K.K() == K.K() && r->K.dist == K.dist && r->K.width == K.width && r->K.height == K.height) return r;
  impl_->rays.push_back(make_pixel_rays(K, threads));
  return impl_->rays.back();
}

ImageF MeshRasterizer::distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, Stats* stats) const {
  const Impl& m = *impl_;
  const auto pr = std::static_pointer_cast<const PixelRays>(rays_of(K, 1));
  ImageF depth(K.width, K.height, 1, 0.f);  // inverse depth while drawing; 0: no surface (yet)
  Stats st;
  Raster raster(*pr, depth, st);
  const Eigen::Isometry3d camera_from_world = world_from_camera.inverse();
  const Eigen::Matrix3f R = camera_from_world.linear().cast<float>();
  const Eigen::Vector3f tr = camera_from_world.translation().cast<float>();
  // Every vertex in the camera frame and, where it can be projected, its pixel (NaN elsewhere).
  struct Vertex {
    Eigen::Vector3f p;
    Eigen::Vector2f px;
  };
  std::vector<Vertex> vs(m.vertices.size());
  const bool inward = m.faces_seen == Faces::kInwardWound;
  // Runs of faces every one of which turns away from the camera: a face's
  // det (below) is n.(a - C) for its world normal n and the camera centre C;
  // with the run's vertices within `radius` of `centre` and its unit normals
  // within the cone, n.(a - C) <= |n| max over the cone of (n^.v + radius)
  // for v = centre - C, and that maximum is |v| cos(theta - alpha) once
  // theta (axis to v) exceeds alpha. Kept clear of 0 by 1e-4 |v|, well past
  // what float rounding moves a face's det.
  std::vector<uint8_t> skip(inward ? m.clusters.size() : 0, 0);
  const Eigen::Vector3d C = world_from_camera.translation();
  for (size_t k = 0; k < skip.size(); ++k) {
    const Impl::Cluster& c = m.clusters[k];
    if (!c.cone) continue;
    const Eigen::Vector3d v = c.centre - C;
    const double most = c.axis.dot(v) * c.cos_a + c.axis.cross(v).norm() * c.sin_a;
    skip[k] = most < -(c.radius + 1e-4 * v.norm());
  }
  // Every vertex in the camera frame and, where it can be projected, its
  // pixel (NaN elsewhere): four at a time, the pose's product written out.
  const size_t nv = m.vertices.size();
  for (size_t i = 0; i < nv; i += 4) {
    alignas(16) float wx[4] = {}, wy[4] = {}, wz[4] = {};
    const size_t n = std::min<size_t>(4, nv - i);
    for (size_t j = 0; j < n; ++j) wx[j] = m.vertices[i + j].x(), wy[j] = m.vertices[i + j].y(), wz[j] = m.vertices[i + j].z();
    const __m128 X = _mm_load_ps(wx), Y = _mm_load_ps(wy), Z = _mm_load_ps(wz);
    auto row = [&](int r) {
      return _mm_add_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_set1_ps(R(r, 0)), X), _mm_mul_ps(_mm_set1_ps(R(r, 1)), Y)),
                                   _mm_mul_ps(_mm_set1_ps(R(r, 2)), Z)),
                        _mm_set1_ps(tr[r]));
    };
    const __m128 x = row(0), y = row(1), z = row(2);
    __m128 px, py;
    raster.pixels4(x, y, z, px, py);
    alignas(16) float ox[4], oy[4], oz[4], opx[4], opy[4];
    _mm_store_ps(ox, x), _mm_store_ps(oy, y), _mm_store_ps(oz, z), _mm_store_ps(opx, px), _mm_store_ps(opy, py);
    for (size_t j = 0; j < n; ++j) vs[i + j] = {{ox[j], oy[j], oz[j]}, {opx[j], opy[j]}};
  }
  const bool distorted = K.has_distortion();
  const float W = float(K.width), H = float(K.height);
  for (size_t fi = 0; fi < m.faces.size(); ++fi) {
    if (!skip.empty() && skip[fi / Impl::kCluster]) {
      const size_t run = std::min(m.faces.size() - fi, Impl::kCluster);
      st.back_faces += run, st.back_faces_in_runs += run;
      fi += run - 1;
      continue;
    }
    const Eigen::Vector3i& f = m.faces[fi];
    const Vertex &va = vs[size_t(f[0])], &vb = vs[size_t(f[1])], &vc = vs[size_t(f[2])];
    const Eigen::Vector2f lo = va.px.cwiseMin(vb.px).cwiseMin(vc.px), hi = va.px.cwiseMax(vb.px).cwiseMax(vc.px);
    const bool projected = lo.allFinite() && hi.allFinite();
    // A projected triangle wholly off the image (a pixel of margin) is culled here.
    if (projected && (hi.x() < -1.5f || hi.y() < -1.5f || lo.x() > W + 0.5f || lo.y() > H + 0.5f)) {
      ++st.triangles_culled;
      continue;
    }
    // The plane through the camera centre and each edge, from the edge's
    // vertices in ascending index order: the two triangles on an edge
    // compute it bitwise the same (up to sign), so they leave no crack.
    TriangleTest t;
    auto edge = [&](int k) {
      const int i = f[(k + 1) % 3], j = f[(k + 2) % 3];
      const Eigen::Vector3f &p = vs[size_t(std::min(i, j))].p, &q = vs[size_t(std::max(i, j))].p;
      t.e[k] = p.cross(q - p);
      if (i > j) t.e[k] = -t.e[k];
    };
    edge(0);
    const Eigen::Vector3f &a = va.p, &b = vb.p, &c = vc.p;
    // det = a.(b x c) = n.a: > 0 where the face's normal points away from the camera.
    const float det = a.dot(t.e[0]);
    if (!(det != 0) || !std::isfinite(det)) {
      ++st.triangles_culled;  // edge-on: its plane holds the camera centre
      continue;
    }
    if (inward && det < 0) {
      ++st.back_faces;  // its outside faces away: behind the surface's front
      continue;
    }
    edge(1), edge(2);
    if (det < 0)
      for (auto& e : t.e) e = -e;
    const Eigen::Vector3d n = (b - a).cross(c - a).cast<double>();
    // One quotient, then products: in double, so the float m is the
    // quotient's rounding all but never changed by the extra step.
    t.m = (n * (1.0 / n.dot(a.cast<double>()))).cast<float>();
    // Under distortion a triangle's edges bow out of its vertices' box: by
    // a fraction of a pixel for small ones, which get that much margin; wide
    // ones are bounded by their edges' samples.
    const float extent = (hi - lo).norm();  // the longest edge is at most the box's diagonal
    if (projected && !(distorted && extent > 16.f)) raster.pixels(t, lo, hi, Raster::kRound + raster.bow() * extent * extent);
    else raster.clipped(t, a, b, c);
  }
  // Inverse depth to distance along the ray, where pixels were drawn: four
  // at a time (a quotient where the pixel has a surface, 0 where not).
  for (int y = raster.drawn_y0(); y <= raster.drawn_y1(); ++y) {
    const size_t row = size_t(y) * size_t(K.width);
    float* d = depth.data.data() + row;
    const float* len = pr->length.data() + row;
    int x = raster.drawn_x0();
    for (; x + 3 <= raster.drawn_x1(); x += 4) {
      const __m128 inv = _mm_loadu_ps(d + x);
      const __m128 hit = _mm_cmpgt_ps(inv, _mm_setzero_ps());
      _mm_storeu_ps(d + x, _mm_and_ps(hit, _mm_div_ps(_mm_loadu_ps(len + x), inv)));
    }
    for (; x <= raster.drawn_x1(); ++x) d[x] = d[x] > 0 ? len[x] / d[x] : 0.f;
  }
  if (stats) *stats = st;
  return depth;
}

}  // namespace s2r
