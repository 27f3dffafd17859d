#include "reconstruct/camera_depth.h"

#include <limits>
#include <mutex>

#include <embree3/rtcore.h>

#include "core/parallel.h"

namespace s2r {

struct MeshRaycaster::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  size_t triangles = 0;
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
    for (size_t i = 0; i < mesh.vertices.size(); ++i)
      for (int k = 0; k < 3; ++k) vb[3 * i + k] = mesh.vertices[i][k];
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

float MeshRaycaster::distance(const Eigen::Vector3f& o, const Eigen::Vector3f& d) const {
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

ImageF MeshRaycaster::distance_image(const Intrinsics& K, const Eigen::Isometry3d& world_from_camera, int threads) const {
  ImageF out(K.width, K.height, 1, 0.f);
  const Eigen::Matrix3f R = world_from_camera.linear().cast<float>();
  const Eigen::Vector3f o = world_from_camera.translation().cast<float>();
  // Undistorting every pixel is the costly part: the rays of the last
  // intrinsics are kept (the cameras of a session share them).
  std::shared_ptr<const std::vector<Eigen::Vector3f>> rays;
  {
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
    rays = impl_->rays;
  }
  parallel_for(K.height, worker_count(threads), [&](int y) {
    for (int x = 0; x < K.width; ++x) {
      const Eigen::Vector3f& r = (*rays)[size_t(y) * K.width + x];
      if (r.z() <= 0) continue;
      out.data[size_t(y) * K.width + x] = distance(o, R * r);
    }
  });
  return out;
}

}  // namespace s2r
