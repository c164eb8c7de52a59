// octofuse: a map that carries its loss map. Each leaf of the map keeps the accumulated
// information loss of its voxels in its own node (OccupancyNode's spare bytes) for as long as
// the map keeps it a leaf; the loss map's tree, the side tree, holds the rest. A voxel's loss is
// carried by its leaf or held by the side tree, never both. Fusions and insertions keep it so;
// anything else that reads the loss map or reshapes the map first settles it: every carried loss
// moved into the side tree, which then is the loss tree an uncarried loss map would hold, node
// for node (each voxel sees the same float additions in the same order, and both are pruned).
#pragma once

#include "octofuse/detail/prune_or_max.hpp"
#include "octofuse/loss_tree.hpp"

#include <cstdint>
#include <cstring>
#include <vector>

namespace octofuse::detail {

/// Adds the loss `v` of the fused leaf `d` of a map that carries its loss map (`lc`: the side
/// tree's cursor at d): carried by d if d carries already or the side tree holds nothing at or
/// around d, else added into the side tree as for an uncarried loss map.
inline void add_carried_loss(OccupancyNode* d, float v, LossAdder& loss, const LossCursor& lc) {
  const bool carried = d->carries_loss();
  if (carried || (lc.active && lc.node == nullptr && lc.within == nullptr)) {
    const float sum = (carried ? d->carried_loss() : 0.0f) + v;
    std::uint32_t bits;
    std::memcpy(&bits, &sum, sizeof bits);
    if (bits != OccupancyNode::kNoLoss) {
      d->set_carried_loss(sum);
      return;
    }
    // the one NaN that means "carries nothing": the side tree takes this voxel's loss
    if (carried) {
      loss.add(lc, d->carried_loss());
      d->drop_carried_loss();
    }
  }
  loss.add(lc, v);
}

/// prune_or_max's `move_aside` for a map that carries its loss map (`lc`: the side tree's
/// cursor at the node ended): eight leaves of one log-odds that carry different losses give
/// them to the side tree, so that the map merges them as an uncarried map does.
struct MoveLossesAside {
  LossAdder& loss;
  const LossCursor& lc;
  bool operator()(OccupancyNode* const* kids) const {
    for (unsigned i = 0; i < 8; ++i) {
      if (!kids[i]->carries_loss()) continue;
      loss.add(loss.child(lc, i), kids[i]->carried_loss());
      kids[i]->drop_carried_loss();
    }
    return true;
  }
};

}  // namespace octofuse::detail

namespace octofuse {

/// Moves every loss the nodes of `tree` carry into `side`, the tree of the loss map they carry
/// (`tree` then carries none).
void move_carried_loss(OccupancyTree& tree, ScalarTree& side);

/// The values and depths of the leaves the loss tree `side` would have once the losses `tree`
/// carries were moved into it (move_carried_loss), in its leaf order, without moving them.
void settled_loss_leaves(const OccupancyTree& tree, const ScalarTree& side,
                         std::vector<float>& values, std::vector<std::uint8_t>& depths);

}  // namespace octofuse
