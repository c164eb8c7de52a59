// octofuse: comparing a map with a reference map, and the voxels that changed between two
// versions of a map.
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace octofuse {

/// Voxel classes: occupied (log-odds > occupancy threshold), free, unknown (no node).
enum VoxelClass : int { kOccupied = 0, kFree = 1, kUnknown = 2 };

/// Statistics of a map against a reference, over finest-level voxels (a coarse leaf counts
/// for all the voxels below it).
struct Comparison {
  /// confusion[reference class][map class], voxel counts
  std::array<std::array<double, 3>, 3> confusion{};
  double kl_sum = 0.0;         ///< sum of KL(p_ref || p_map) over voxels the reference knows
                               ///< (an unknown map voxel counts as p = 0.5)
  double both_known = 0.0;     ///< voxels both maps know
  double overconfident = 0.0;  ///< of those: |l_map| > |l_ref| + tol
  double abs_diff_sum = 0.0;   ///< sum of |l_map - l_ref| over voxels both know
};

/// A reference map as compare_maps reads it: its nodes' values and children in one array,
/// each node's children side by side, depth first. Made once (one walk of the map) and
/// compared with many maps; it holds nothing of the map it was made from, which may change
/// or go afterwards.
class ReferenceMap {
 public:
  struct Node {
    float value;          ///< stored log-odds
    std::uint32_t first;  ///< index of the first child (children in child order)
    std::uint32_t kids;   ///< mask of the children (none: a leaf)
  };

  explicit ReferenceMap(const OccupancyMap& ref);

  /// The nodes, the root first; empty for an empty map.
  const std::vector<Node>& nodes() const { return nodes_; }
  /// An empty map of the reference's parameters (for the compatibility check).
  const OccupancyMap& grid() const { return grid_; }
  std::size_t memory_bytes() const { return nodes_.capacity() * sizeof(Node); }

 private:
  OccupancyMap grid_;
  std::vector<Node> nodes_;
};

/// Compares `map` with the reference `ref` (e.g. an agent's map with the centralized map),
/// walking both together through the children either of the two has. `tol` is the
/// over-confidence tolerance in log-odds; `occ_threshold` the occupancy threshold in log-odds
/// (OctoMap's default: 0).
Comparison compare_maps(const ReferenceMap& ref, const OccupancyMap& map, double tol,
                        double occ_threshold = 0.0);

/// The voxels of `current` that are new or have another value than in `previous`, as a map
/// (the content of a delta message). Both maps must be compatible.
std::unique_ptr<OccupancyMap> changed_voxels(const OccupancyMap& current,
                                             const OccupancyMap& previous);

/// The voxels of `delta` that change a receiver's copy `held` most, as many as fit in an
/// OctoMap stream of `max_nodes` nodes: its leaves ranked by |log-odds - held's| (held's node
/// at that place, 0 where it has none), largest first (ties in leaf order), taken in that
/// order until the next would not fit. `taken` is set to how many leaves were taken.
std::unique_ptr<OccupancyMap> most_informative_voxels(const OccupancyMap& delta,
                                                      const OccupancyMap& held,
                                                      std::size_t max_nodes, std::size_t& taken);

/// `held` with the leaves of `delta` written over it: the receiver's copy after `delta`
/// (a leaf of `delta` replaces everything of `held` below it).
std::unique_ptr<OccupancyMap> overlaid(const OccupancyMap& held, const OccupancyMap& delta);

}  // namespace octofuse
