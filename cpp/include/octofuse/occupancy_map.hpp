// octofuse: the one adapter around the occupancy tree (parameters, insertion, leaf export).
#pragma once

#include "octofuse/tree.hpp"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace octofuse {

namespace detail {
class CarryingAccess;
}  // namespace detail

/// Error raised for unreadable, truncated or foreign map files; the message names the file.
class MapFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Smallest and largest voxel edge length (metres) a map may have: OctoMap's 16-bit keys
/// address 65536 voxels per axis, so the map spans +-3.3 m at the smallest and the float
/// coordinates of its points keep sub-voxel precision at the largest.
inline constexpr double kMinResolution = 1e-4;
inline constexpr double kMaxResolution = 1e3;

/// Sensor model and clamping of an occupancy map, as probabilities.
struct MapParams {
  double resolution = 0.05;   ///< edge length of the finest voxel in metres
  double prob_hit = 0.7;      ///< P(occupied | hit)
  double prob_miss = 0.4;     ///< P(occupied | ray passed through)
  double clamp_min = 0.1192;  ///< lower clamping threshold (probability)
  double clamp_max = 0.971;   ///< upper clamping threshold (probability)

  /// Throws std::invalid_argument naming the offending value if the parameters are unusable.
  void validate() const;
};

/// Which leaves of a map: log-odds > 0, <= 0, or every leaf.
enum class LeafClass { Occupied, Free, All };

/// Whether a leaf of value `log_odds` is of class `which`.
inline bool of_class(float log_odds, LeafClass which) {
  if (which == LeafClass::All) return true;
  return which == LeafClass::Occupied ? log_odds > 0 : log_odds <= 0;
}

/// Leaves of a tree as flat arrays (structure of arrays).
struct LeafArrays {
  std::vector<double> centers;       ///< 3 * n, x y z interleaved
  std::vector<double> sizes;         ///< n, edge length in metres
  std::vector<float> values;         ///< n, stored value (log-odds for occupancy maps)
  std::vector<std::uint8_t> depths;  ///< n, tree depth of the leaf (16 = finest)
};

namespace detail {

/// Appends a leaf of `tree` (key and depth as OctoMap's leaf iterator gives them) to `out`:
/// its centre, edge length, value, depth.
template <class Tree>
void append_leaf(LeafArrays& out, const Tree& tree, const octomap::OcTreeKey& k, unsigned d,
                 float value) {
  for (int a = 0; a < 3; ++a) out.centers.push_back(tree.keyToCoord(k[a], d));
  out.sizes.push_back(tree.getNodeSize(d));
  out.values.push_back(value);
  out.depths.push_back(static_cast<std::uint8_t>(d));
}

}  // namespace detail

/// An OctoMap occupancy tree with octofuse's parameters; owns its OccupancyTree.
class OccupancyMap {
 public:
  explicit OccupancyMap(const MapParams& params);

  /// Deep copy (all nodes).
  OccupancyMap(const OccupancyMap& other);
  OccupancyMap& operator=(const OccupancyMap&) = delete;

  /// Inserts one scan with OctoMap's ray casting update (OctoMap's insertPointCloud).
  /// `xyz` holds n points (x y z interleaved) in the map frame; rays longer than max_range
  /// (if >= 0) clear free space up to max_range only. Inner nodes are updated. The scan is
  /// checked first (check_scan()) and inserted only if every ray can be traced: throws
  /// std::invalid_argument naming the first point that cannot, and leaves the map unchanged.
  template <class Real>
  void insert_scan(const Real* xyz, std::size_t n, const double origin[3], double max_range);

  /// Same as insert_scan() for points given in the sensor frame: `pose` is the 4x4
  /// row-major sensor-to-map transform; the sensor origin is its translation.
  template <class Real>
  void insert_scan_from_sensor(const Real* xyz, std::size_t n, const double pose[16],
                               double max_range);

  /// Centres, sizes and log-odds of the leaves of class `which`.
  LeafArrays leaves(LeafClass which = LeafClass::All) const;

  const MapParams& params() const { return params_; }
  std::size_t num_leaves() const { return tree_->getNumLeafNodes(); }
  /// Finest voxels the map knows: a leaf at depth d counts for the 8^(16-d) below it.
  std::uint64_t known_voxels() const;
  std::size_t num_nodes() const { return tree_->size(); }
  std::size_t memory_bytes() const { return tree_->memoryUsage(); }
  /// The tree, to read. Its leaves may carry losses (carried_loss.hpp).
  const OccupancyTree& tree() const { return *tree_; }
  /// The tree, to change: the losses its nodes carry are settled first (settle_loss()), so
  /// that the change (OctoMap's own updates and pruning, new nodes) finds nodes that carry
  /// nothing.
  OccupancyTree& settled_tree() {
    settle_loss();
    return *tree_;
  }

  /// Clamping thresholds as the float log-odds OctoMap stores.
  float clamp_min_logodds() const { return tree_->getClampingThresMinLog(); }
  float clamp_max_logodds() const { return tree_->getClampingThresMaxLog(); }

  /// The loss tree whose losses this map's nodes carry (carried_loss.hpp), or null. A copy of
  /// the map carries none.
  ScalarTree* carried_loss() const { return carried_loss_; }
  /// Makes the map's fusions into it that add into `loss` keep those losses in the map's
  /// nodes (null: none), after settling what it carried before. `loss` must outlive this.
  void carry_loss(ScalarTree* loss);
  /// Moves every loss the map carries into its loss tree (the binding stays); at once if no
  /// fusion has added a loss into the nodes since the last time.
  void settle_loss();
  /// Drops every loss the map carries and clears its loss tree (the binding stays).
  void drop_loss();
  /// Removes every voxel, freeing the nodes; the losses it carries are settled into its loss
  /// tree first (`keep_loss`) or go with the nodes (to free the map and its loss map together).
  void clear(bool keep_loss = true);

 private:
  // the core's walks that change the tree with its carried losses in place (map_access.hpp)
  friend class detail::CarryingAccess;

  MapParams params_;
  std::unique_ptr<OccupancyTree> tree_;
  ScalarTree* carried_loss_ = nullptr;
  bool carrying_ = false;  // a node may carry a loss (false: settling finds none)
};

/// Leaves of a scalar tree.
LeafArrays scalar_leaves(const ScalarTree& tree);

/// Throws std::invalid_argument if two maps do not share a voxel grid (different
/// resolution): the same rays then pass the same voxels of both.
void check_same_grid(const OccupancyMap& a, const OccupancyMap& b);

/// Throws std::invalid_argument saying what differs if two maps cannot be combined voxel by
/// voxel (different resolution or clamping).
void check_compatible(const OccupancyMap& a, const OccupancyMap& b);
}  // namespace octofuse
