// octofuse: scan insertion into an OccupancyMap (OctoMap's ray casting update).
#include "octofuse/occupancy_map.hpp"

#include <octomap/Pointcloud.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace octofuse {

template <class Real>
void OccupancyMap::insert_scan(const Real* xyz, std::size_t n, const double origin[3],
                               double max_range) {
  octomap::Pointcloud cloud;
  cloud.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    cloud.push_back(static_cast<float>(xyz[3 * i]), static_cast<float>(xyz[3 * i + 1]),
                    static_cast<float>(xyz[3 * i + 2]));
  }
  const octomap::point3d o(static_cast<float>(origin[0]), static_cast<float>(origin[1]),
                           static_cast<float>(origin[2]));
  tree_->insertPointCloud(cloud, o, max_range, /*lazy_eval=*/false, /*discretize=*/false);
}

template <class Real>
void OccupancyMap::insert_scan_from_sensor(const Real* xyz, std::size_t n, const double pose[16],
                                           double max_range) {
  const Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(pose);
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const Eigen::Vector3d t = T.topRightCorner<3, 1>();
  octomap::Pointcloud cloud;
  cloud.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    const Eigen::Vector3d q = R * p + t;
    cloud.push_back(static_cast<float>(q.x()), static_cast<float>(q.y()),
                    static_cast<float>(q.z()));
  }
  const octomap::point3d o(static_cast<float>(t.x()), static_cast<float>(t.y()),
                           static_cast<float>(t.z()));
  tree_->insertPointCloud(cloud, o, max_range, /*lazy_eval=*/false, /*discretize=*/false);
}

template void OccupancyMap::insert_scan<float>(const float*, std::size_t, const double*, double);
template void OccupancyMap::insert_scan<double>(const double*, std::size_t, const double*, double);
template void OccupancyMap::insert_scan_from_sensor<float>(const float*, std::size_t,
                                                           const double*, double);
template void OccupancyMap::insert_scan_from_sensor<double>(const double*, std::size_t,
                                                            const double*, double);

}  // namespace octofuse
