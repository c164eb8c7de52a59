// octofuse: OccupancyMap, the adapter around OccupancyTree.
#include "octofuse/occupancy_map.hpp"

#include "octofuse/carried_loss.hpp"
#include "octofuse/detail/text.hpp"
#include "octofuse/scan_check.hpp"

#include "walk.hpp"

#include <octomap/Pointcloud.h>

#include <Eigen/Core>

#include <cmath>
#include <string>

namespace octofuse {

namespace {

// The leaves whose value `keep` accepts; room is made for `expected` of them.
template <class Tree, class Keep>
LeafArrays collect_leaves(const Tree& tree, Keep keep, std::size_t expected) {
  LeafArrays out;
  out.centers.reserve(3 * expected);
  out.sizes.reserve(expected);
  out.values.reserve(expected);
  out.depths.reserve(expected);
  detail::for_each_leaf(tree, [&](const auto& node, const octomap::OcTreeKey& k, unsigned d) {
    if (keep(node.getValue())) detail::append_leaf(out, tree, k, d, node.getValue());
  });
  return out;
}

void insert_cloud(OccupancyTree& tree, const octomap::Pointcloud& cloud,
                  const octomap::point3d& origin, double max_range) {
  const ScanCheck check(tree, origin, max_range);
  for (std::size_t i = 0; i < cloud.size(); ++i) check.check(i, cloud[i]);
  tree.insertPointCloud(cloud, origin, max_range, /*lazy_eval=*/false, /*discretize=*/false);
}

}  // namespace

void MapParams::validate() const {
  using detail::shortest;
  auto bad = [](const std::string& what, double v, const std::string& expected) {
    throw std::invalid_argument(what + " = " + shortest(v) + ": expected " + expected);
  };
  if (!(resolution >= kMinResolution && resolution <= kMaxResolution)) {
    bad("resolution", resolution,
        "a voxel size from " + shortest(kMinResolution) + " to " + shortest(kMaxResolution) + " m");
  }
  if (!(prob_hit > 0.5 && prob_hit < 1.0)) bad("prob_hit", prob_hit, "a probability in (0.5, 1)");
  if (!(prob_miss > 0.0 && prob_miss < 0.5))
    bad("prob_miss", prob_miss, "a probability in (0, 0.5)");
  if (!(clamp_min > 0.0 && clamp_min < 0.5))
    bad("clamping min", clamp_min, "a probability in (0, 0.5)");
  if (!(clamp_max > 0.5 && clamp_max < 1.0))
    bad("clamping max", clamp_max, "a probability in (0.5, 1)");
}

OccupancyMap::OccupancyMap(const MapParams& params) : params_(params) {
  params_.validate();
  tree_ = std::make_unique<OccupancyTree>(params_.resolution);
  tree_->setProbHit(params_.prob_hit);
  tree_->setProbMiss(params_.prob_miss);
  tree_->setClampingThresMin(params_.clamp_min);
  tree_->setClampingThresMax(params_.clamp_max);
}

OccupancyMap::OccupancyMap(const OccupancyMap& other)
    : params_(other.params_), tree_(std::make_unique<OccupancyTree>(*other.tree_)) {
  tree_->setProbHit(params_.prob_hit);
  tree_->setProbMiss(params_.prob_miss);
  tree_->setClampingThresMin(params_.clamp_min);
  tree_->setClampingThresMax(params_.clamp_max);
}

void OccupancyMap::carry_loss(ScalarTree* loss) {
  settle_loss();
  carried_loss_ = loss;
}

void OccupancyMap::settle_loss() {
  if (!carrying_) return;
  move_carried_loss(*tree_, *carried_loss_);
  carrying_ = false;
}

void OccupancyMap::drop_loss() {
  if (carried_loss_ == nullptr) return;
  if (carrying_) {
    for (auto it = tree_->begin_tree(), end = tree_->end_tree(); it != end; ++it)
      it->drop_carried_loss();
    carrying_ = false;
  }
  carried_loss_->clear();
}

void OccupancyMap::clear(bool keep_loss) {
  if (keep_loss) settle_loss();
  tree_->clear();
  carrying_ = false;
}

// Single scans through OctoMap's own insertPointCloud().
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
  // OctoMap's own updates merge nodes without moving carried losses aside
  insert_cloud(settled_tree(), cloud, o, max_range);
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
  // OctoMap's own updates merge nodes without moving carried losses aside
  insert_cloud(settled_tree(), cloud, o, max_range);
}

template void OccupancyMap::insert_scan<float>(const float*, std::size_t, const double*, double);
template void OccupancyMap::insert_scan<double>(const double*, std::size_t, const double*, double);
template void OccupancyMap::insert_scan_from_sensor<float>(const float*, std::size_t, const double*,
                                                           double);
template void OccupancyMap::insert_scan_from_sensor<double>(const double*, std::size_t,
                                                            const double*, double);

LeafArrays OccupancyMap::leaves(LeafClass which) const {
  // all: the node count the tree keeps (leaves and more); a class: grown as found
  return collect_leaves(
      *tree_, [which](float v) { return of_class(v, which); },
      which == LeafClass::All ? tree_->size() : 0);
}

std::uint64_t OccupancyMap::known_voxels() const {
  std::uint64_t n = 0;
  for (auto it = tree_->begin_leafs(), end = tree_->end_leafs(); it != end; ++it)
    n += std::uint64_t{1} << (3 * (tree_->getTreeDepth() - it.getDepth()));
  return n;
}
LeafArrays scalar_leaves(const ScalarTree& tree) {
  return collect_leaves(
      tree, [](float) { return true; }, tree.size());
}

void check_same_grid(const OccupancyMap& a, const OccupancyMap& b) {
  const MapParams &pa = a.params(), &pb = b.params();
  if (std::fabs(pa.resolution - pb.resolution) > 1e-9 * pa.resolution) {
    throw std::invalid_argument(
        "maps have different resolutions (" + std::to_string(pa.resolution) + " m and " +
        std::to_string(pb.resolution) + " m); use maps built at the same resolution");
  }
}

void check_compatible(const OccupancyMap& a, const OccupancyMap& b) {
  check_same_grid(a, b);
  const MapParams &pa = a.params(), &pb = b.params();
  if (a.clamp_min_logodds() != b.clamp_min_logodds() ||
      a.clamp_max_logodds() != b.clamp_max_logodds()) {
    throw std::invalid_argument(
        "maps have different clamping thresholds ([" + std::to_string(pa.clamp_min) + ", " +
        std::to_string(pa.clamp_max) + "] and [" + std::to_string(pb.clamp_min) + ", " +
        std::to_string(pb.clamp_max) + "]); fuse maps built with the same clamping");
  }
}

}  // namespace octofuse
