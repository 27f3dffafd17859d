#include "reconstruct/camera_depth.h"

#include <algorithm>
#include <limits>
#include <mutex>

#include <embree3/rtcore.h>

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

void MeshRaycaster::prepare_rays(const Intrinsics& K, int threads) const { rays_of(K, threads); }

ImageF MeshRaycaster::distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, int threads,
                                     const ImageF* reach) const {
  ImageF out(K.width, K.height, 1, 0.f);
  if (reach && (reach->width != K.width || reach->height != K.height)) reach = nullptr;  // another size: every pixel
  const Eigen::Matrix3f R = world_from_camera.linear().cast<float>();
  const Eigen::Vector3f o = world_from_camera.translation().cast<float>();
  const std::shared_ptr<const std::vector<Eigen::Vector3f>> rays = rays_of(K, threads);
  // Eight pixels of a row at a time, of those whose rays meet the mesh's
  // bounds (and are wanted): neighbouring rays traced as one packet.
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
      const size_t p = size_t(y) * K.width + x;
      const float far = reach ? reach->data[p] : std::numeric_limits<float>::infinity();
      if (!(far > 0)) continue;
      const Eigen::Vector3f& r = (*rays)[p];
      if (r.z() <= 0) continue;
      const Eigen::Vector3f d = R * r;
      if (!meets(impl_->bounds, o, d)) continue;
      const int k = lanes++;
      xs[k] = x;
      valid[k] = -1;
      rh.ray.org_x[k] = o.x(), rh.ray.org_y[k] = o.y(), rh.ray.org_z[k] = o.z();
      rh.ray.dir_x[k] = d.x(), rh.ray.dir_y[k] = d.y(), rh.ray.dir_z[k] = d.z();
      rh.ray.tnear[k] = 0;
      rh.ray.tfar[k] = far;
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

}  // namespace s2r
