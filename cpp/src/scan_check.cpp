// octofuse: bounds of a scan's rays in an OcTree.
#include "octofuse/scan_check.hpp"

#include "octofuse/detail/text.hpp"

#include <cmath>
#include <cstdlib>
#include <stdexcept>

namespace octofuse {

namespace {

std::string point_text(const octomap::point3d& p) {
  return "(" + detail::shortest(p.x()) + ", " + detail::shortest(p.y()) + ", " +
         detail::shortest(p.z()) + ")";
}

bool finite(const octomap::point3d& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}

}  // namespace

std::size_t max_ray_voxels() {
  // the DDA adds at most the L1 key distance + 7 keys, and asserts a free slot after each
  static const std::size_t n = octomap::KeyRay().sizeMax() - 100;
  return n;
}

ScanCheck::ScanCheck(const OccupancyTree& grid, const octomap::point3d& origin, double max_range,
                     std::string where)
    : grid_(grid),
      origin_(origin),
      max_range_(max_range),
      factor_(1.0 / grid.getResolution()),
      where_(std::move(where)) {
  if (!finite(origin)) throw std::invalid_argument(where_ + "the sensor origin is not finite");
  for (int a = 0; a < 3; ++a) {
    if (!key_of(origin(a), origin_key_[a])) {
      throw std::invalid_argument(where_ + "the sensor origin " + point_text(origin) +
                                  " lies outside the map's extent: " + extent_text());
    }
  }
}

// OctoMap's coordToKeyChecked() without its undefined int cast of far coordinates.
bool ScanCheck::key_of(float coord, long& key) const {
  const double half = static_cast<double>(1u << (grid_.getTreeDepth() - 1));
  const double s = std::floor(factor_ * static_cast<double>(coord));
  if (!(s >= -half && s < half)) return false;
  key = static_cast<long>(s + half);
  return true;
}

std::string ScanCheck::extent_text() const {
  const double half = static_cast<double>(1u << (grid_.getTreeDepth() - 1));
  const double r = grid_.getResolution();
  return "at resolution " + detail::shortest(r) + " m an OcTree spans [" +
         detail::shortest(-half * r) + ", " + detail::shortest(half * r) +
         ") m along each axis around the map origin";
}

void ScanCheck::check(std::size_t row, const octomap::point3d& p) const {
  auto at = [&] { return where_ + "point row " + std::to_string(row); };
  if (!finite(p)) {
    throw std::invalid_argument(where_ + "points hold a non-finite coordinate at row " +
                                std::to_string(row) + "; drop NaN/inf points before inserting");
  }
  long key[3];
  for (int a = 0; a < 3; ++a) {
    if (!key_of(p(a), key[a])) {
      throw std::invalid_argument(at() + " " + point_text(p) +
                                  " lies outside the map's extent: " + extent_text());
    }
  }
  // the ray's end as OccupancyOcTreeBase::computeUpdate() computes it
  octomap::point3d end = p;
  if (!(max_range_ < 0.0 || (p - origin_).norm() <= max_range_)) {
    end = origin_ + (p - origin_).normalized() * static_cast<float>(max_range_);
    for (int a = 0; a < 3; ++a) {
      if (!key_of(end(a), key[a])) {
        throw std::invalid_argument(at() + ": its ray, cut to max_range, ends at " +
                                    point_text(end) +
                                    ", outside the map's extent: " + extent_text());
      }
    }
  }
  const long voxels = std::labs(key[0] - origin_key_[0]) + std::labs(key[1] - origin_key_[1]) +
                      std::labs(key[2] - origin_key_[2]);
  if (voxels > 0 && voxels <= 3) {
    // computeRayKeys() normalises the ray in float: a ray so short that its length rounds to
    // zero (the sensor origin on a voxel face or corner, the end just across: at most one
    // voxel away along each axis) steps forever
    octomap::point3d direction = end - origin_;
    const float length = static_cast<float>(direction.norm());
    direction /= length;
    if (!(length > 0.0f) || !finite(direction)) {
      const std::string from = detail::shortest(length) + " m from the sensor origin " +
                               point_text(origin_) + " but in another voxel: ";
      throw std::invalid_argument(
          end == p ? at() + " " + point_text(p) + " lies " + from +
                         "too short a ray for OctoMap to trace; drop points at the sensor origin"
                   : at() + " " + point_text(p) + ": its ray cut to max_range (" +
                         detail::shortest(max_range_) + " m) ends " + from +
                         "too short for OctoMap to trace; give a max_range of at least the "
                         "voxel size, or <= 0 for no limit");
    }
  }
  if (static_cast<std::size_t>(voxels) > max_ray_voxels()) {
    const double r = grid_.getResolution();
    const double safe = std::floor(static_cast<double>(max_ray_voxels()) * r / std::sqrt(3.0));
    throw std::invalid_argument(at() + " " + point_text(p) + ": its ray from the sensor origin " +
                                point_text(origin_) + " crosses about " + std::to_string(voxels) +
                                " voxels, more than the " + std::to_string(max_ray_voxels()) +
                                " OctoMap traces in one ray; set max_range to at most " +
                                detail::shortest(safe) + " m (at resolution " +
                                detail::shortest(r) + " m) or use a coarser resolution");
  }
}

}  // namespace octofuse
