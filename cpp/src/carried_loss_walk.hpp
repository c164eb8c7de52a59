// octofuse: the steps of a walk that fuses into a map carrying its loss map
// (octofuse/carried_loss.hpp): where a fused leaf's loss goes, and what merging leaves that
// carry different losses does with them.
#pragma once

#include "octofuse/tree.hpp"

#include "loss_tree.hpp"

#include <cstdint>
#include <cstring>

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
