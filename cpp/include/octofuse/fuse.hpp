// octofuse: tree-level fusion of two occupancy maps with a per-voxel rule.
#pragma once

#include "octofuse/occupancy_map.hpp"
#include "octofuse/rules.hpp"
#include "octofuse/voxel_fusion.hpp"

#include <cstddef>
#include <memory>

namespace octofuse {

/// Inputs of at least this many nodes together get fuse_maps() arenas (4 MiB of nodes).
inline constexpr std::size_t kArenaMinNodes = std::size_t(1) << 18;

/// Result of fusing two maps: the fused map and the per-voxel information loss
/// KL(p_NB || p_fused) (nats), a tree over the same keys as the fused map.
struct FusionResult {
  std::unique_ptr<OccupancyMap> map;
  std::unique_ptr<ScalarTree> info_loss;
  FusionCounts counts;  ///< finest voxels fused and copied, and their summed loss
};

/// Fuses `a` and `b` voxel by voxel: the result equals VoxelFusion<rule, unknown> on every
/// voxel of the two trees expanded to the finest level (a coarse leaf stands for all the
/// voxels below it). Both trees are walked once, together, from the root. Throws
/// std::invalid_argument for incompatible maps (check_compatible()). Inner nodes hold the max
/// of their children; nodes whose eight children are equal leaves are pruned.
///
/// If the inputs have `arena_min_nodes` nodes or more together, the two new trees are built
/// in arenas of their own (TreeArena): freeing them then gives back slabs, not nodes one by
/// one, for as long as nothing was added to them since. An arena keeps up to two 1 MiB slabs
/// partly unused, hence the threshold.
FusionResult fuse_maps(const OccupancyMap& a, const OccupancyMap& b, Rule rule,
                       UnknownPolicy unknown, std::size_t arena_min_nodes = kArenaMinNodes);

}  // namespace octofuse
