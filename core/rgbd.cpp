#include "core/rgbd.h"

#include <cmath>

namespace s2r {

ColoredPoints depth_to_points(const ImageU16& depth, double unit_m, const Intrinsics& depth_K,
                              const Eigen::Isometry3d& color_from_depth, const ImageU8* color,
                              const Intrinsics* color_K, int stride) {
  ColoredPoints out;
  if (stride < 1) stride = 1;
  for (int y = 0; y < depth.height; y += stride)
    for (int x = 0; x < depth.width; x += stride) {
      const uint16_t d = depth.at(x, y);
      if (d == 0) continue;
      auto p = depth_K.unproject({double(x), double(y)}, d * unit_m);
      if (!p) continue;
      const Eigen::Vector3d pc = color_from_depth * *p;
      std::array<uint8_t, 3> rgb{128, 128, 128};
      if (color && color_K) {
        if (auto px = color_K->project(pc); px && color_K->contains(*px)) {
          const int u = static_cast<int>(std::lround(px->x()));
          const int v = static_cast<int>(std::lround(px->y()));
          for (int c = 0; c < 3; ++c)
            rgb[c] = color->at(u, v, color->channels >= 3 ? c : 0);
        }
      }
      out.points.push_back(pc.cast<float>());
      out.colors.push_back(rgb);
    }
  return out;
}

PointScan depth_to_scan(const ImageU16& depth, double unit_m, const Intrinsics& depth_K,
                        const Eigen::Isometry3d& color_from_depth) {
  PointScan scan;
  scan.grid_width = depth.width;
  scan.grid_height = depth.height;
  scan.grid_index.assign(static_cast<size_t>(depth.width) * depth.height, -1);
  for (int y = 0; y < depth.height; ++y)
    for (int x = 0; x < depth.width; ++x) {
      const uint16_t d = depth.at(x, y);
      if (d == 0) continue;
      auto p = depth_K.unproject({double(x), double(y)}, d * unit_m);
      if (!p || !p->allFinite()) continue;
      scan.grid_index[static_cast<size_t>(y) * depth.width + x] = static_cast<int32_t>(scan.points.size());
      scan.points.push_back((color_from_depth * *p).cast<float>());
    }
  return scan;
}

}  // namespace s2r
