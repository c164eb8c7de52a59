// octofuse: tree-level fusion of two occupancy maps with a per-voxel rule.
#pragma once

#include "octofuse/occupancy_map.hpp"
#include "octofuse/rules.hpp"
#include "octofuse/voxel_fusion.hpp"

#include <cstddef>
#include <memory>

namespace octofuse {

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
FusionResult fuse_maps(const OccupancyMap& a, const OccupancyMap& b, Rule rule,
                       UnknownPolicy unknown);

}  // namespace octofuse
