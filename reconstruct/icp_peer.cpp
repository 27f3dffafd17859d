// PCL is confined to this unit and view_cloud.cpp.
#include "reconstruct/icp_peer.h"

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>

namespace s2r {

namespace {

pcl::PointCloud<pcl::PointNormal>::Ptr to_pcl(const ViewCloud& c) {
  auto cloud = pcl::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  for (size_t i = 0; i < c.size(); ++i) {
    pcl::PointNormal p;
    p.x = c.points[i].x(), p.y = c.points[i].y(), p.z = c.points[i].z();
    p.normal_x = c.normals[i].x(), p.normal_y = c.normals[i].y(), p.normal_z = c.normals[i].z();
    cloud->push_back(p);
  }
  return cloud;
}

}  // namespace

std::vector<Eigen::Isometry3d> chain_icp(const std::vector<RegistrationView>& views, const IcpPeerOptions& o) {
  std::vector<Eigen::Isometry3d> poses;
  if (views.empty()) return poses;
  poses.push_back(views[0].initial);
  auto target = to_pcl(downsample(views[0].cloud, o.voxel_m));
  for (size_t k = 1; k < views.size(); ++k) {
    auto source = to_pcl(downsample(views[k].cloud, o.voxel_m));
    pcl::IterativeClosestPointWithNormals<pcl::PointNormal, pcl::PointNormal> icp;
    icp.setInputSource(source);
    icp.setInputTarget(target);
    icp.setMaximumIterations(o.max_iterations);
    icp.setMaxCorrespondenceDistance(o.max_correspondence_m);
    icp.setTransformationEpsilon(1e-12);
    icp.setEuclideanFitnessEpsilon(1e-14);
    // The starting relative pose: from the views' initial poses.
    const Eigen::Isometry3d guess = views[k - 1].initial.inverse() * views[k].initial;
    pcl::PointCloud<pcl::PointNormal> aligned;
    icp.align(aligned, guess.matrix().cast<float>());
    Eigen::Isometry3d rel = Eigen::Isometry3d::Identity();
    const Eigen::Matrix4d m = icp.getFinalTransformation().cast<double>();
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(m.topLeftCorner<3, 3>(), Eigen::ComputeFullU | Eigen::ComputeFullV);
    rel.linear() = svd.matrixU() * svd.matrixV().transpose();
    rel.translation() = m.topRightCorner<3, 1>();
    poses.push_back(poses.back() * rel);
    target = source;
  }
  return poses;
}

}  // namespace s2r
