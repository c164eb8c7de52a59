// octofuse: a map that carries its loss map. Each leaf of the map keeps the accumulated
// information loss of its voxels in its own node (OccupancyNode's spare bytes) for as long as
// the map keeps it a leaf; the loss map's tree, the side tree, holds the rest. A voxel's loss is
// carried by its leaf or held by the side tree, never both. Fusions and insertions keep it so;
// anything else that reads the loss map or reshapes the map first settles it: every carried loss
// moved into the side tree, which then is the loss tree an uncarried loss map would hold, node
// for node (each voxel sees the same float additions in the same order, and both are pruned).
#pragma once

#include "octofuse/tree.hpp"

#include <cstdint>
#include <vector>

namespace octofuse {

/// Moves every loss the nodes of `tree` carry into `side`, the tree of the loss map they carry
/// (`tree` then carries none).
void move_carried_loss(OccupancyTree& tree, ScalarTree& side);

/// The values and depths of the leaves the loss tree `side` would have once the losses `tree`
/// carries were moved into it (move_carried_loss), in its leaf order, without moving them.
void settled_loss_leaves(const OccupancyTree& tree, const ScalarTree& side,
                         std::vector<float>& values, std::vector<std::uint8_t>& depths);

}  // namespace octofuse
