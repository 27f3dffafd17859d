#include "render/gl_camera.h"

namespace s2r {

Eigen::Matrix4f gl_projection(const Intrinsics& K, float n, float f) {
  const float w = static_cast<float>(K.width), h = static_cast<float>(K.height);
  Eigen::Matrix4f P = Eigen::Matrix4f::Zero();
  // x_ndc = 2 (u + 0.5) / w - 1 with u = fx x/z + cx.
  P(0, 0) = 2.f * static_cast<float>(K.fx) / w;
  P(0, 2) = (2.f * static_cast<float>(K.cx) + 1.f) / w - 1.f;
  // y_ndc = 1 - 2 (v + 0.5) / h: image row 0 at the top.
  P(1, 1) = -2.f * static_cast<float>(K.fy) / h;
  P(1, 2) = 1.f - (2.f * static_cast<float>(K.cy) + 1.f) / h;
  // z in [n, f] -> [-1, 1], w = z.
  P(2, 2) = (f + n) / (f - n);
  P(2, 3) = -2.f * f * n / (f - n);
  P(3, 2) = 1.f;
  return P;
}

}  // namespace s2r
