// octofuse: the core's write access to a map's tree that leaves the losses its nodes carry in
// place (octofuse/carried_loss.hpp). Everything else changes a map through
// OccupancyMap::settled_tree(), which settles them first.
#pragma once

#include "octofuse/occupancy_map.hpp"

namespace octofuse::detail {

/// For the changes that keep each voxel's loss where it is (carried by its leaf or held by the
/// loss tree): fusions and batched insertion, which move carried losses aside before they merge
/// nodes (carried_loss_walk.hpp), and rewrites of values or parameters that merge nothing.
class CarryingAccess {
 public:
  static OccupancyTree& tree(OccupancyMap& map) { return *map.tree_; }

  /// Whether a fusion into `map` that adds into `loss` keeps those losses in the map's nodes
  /// (`loss` is the tree the map carries); if not, what the map carries is settled first, so
  /// that the fusion merges nodes as in a map that carries nothing.
  static bool start_fusion(OccupancyMap& map, ScalarTree* loss) {
    if (loss != nullptr && loss == map.carried_loss_) {
      map.carrying_ = true;
      return true;
    }
    map.settle_loss();
    return false;
  }
};

}  // namespace octofuse::detail
