// octofuse: the checks that make a scan safe to trace in an OcTree.
//
// OctoMap traces each ray into a fixed buffer of keys (octomap::KeyRay, 100,000 keys) whose
// bound is only asserted, and converts coordinates to keys through an int cast that is
// undefined beyond the tree's extent. Every ray is checked here before it is traced, by
// OctoMap or by octofuse's own tracer (detail/ray_codes.hpp), which takes OctoMap's steps.
#pragma once

#include "octofuse/tree.hpp"

#include <cstddef>
#include <string>

namespace octofuse {

/// Most voxels one ray may cross (OctoMap's key buffer less a margin for its rounding).
std::size_t max_ray_voxels();

/// Checks the rays of one scan (origin and points in the map frame, as the floats OctoMap
/// traces) against a tree, with insertPointCloud()'s max_range semantics: a ray longer than
/// max_range (if >= 0) is cut to max_range and its point not inserted.
class ScanCheck {
 public:
  /// `where` prefixes messages (e.g. "scan 3: "). Throws std::invalid_argument if the origin
  /// is not finite or lies outside the tree's extent.
  ScanCheck(const OccupancyTree& grid, const octomap::point3d& origin, double max_range,
            std::string where = {});

  /// Throws std::invalid_argument naming the row if the point is not finite, lies outside the
  /// tree's extent (32768 voxels from the centre along each axis), or its ray crosses more
  /// than max_ray_voxels() voxels.
  void check(std::size_t row, const octomap::point3d& p) const;

 private:
  bool key_of(float coord, long& key) const;
  std::string extent_text() const;

  const OccupancyTree& grid_;
  octomap::point3d origin_;
  long origin_key_[3];
  double max_range_;
  double factor_;  // 1 / resolution, as OctoMap computes keys
  std::string where_;
};

}  // namespace octofuse
