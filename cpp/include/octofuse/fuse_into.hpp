// octofuse: in-place fusion of a received map into an agent's own map.
#pragma once

#include "octofuse/fuse.hpp"

#include <utility>

namespace octofuse {

/// Counts of an in-place fusion, in finest voxels: `copied` counts the voxels known only to
/// the message (policy Copy; voxels only the destination knows are not visited).
using FuseIntoStats = FusionCounts;

/// Fuses `msg` into `dst` in place, voxel by voxel, with the same per-voxel result as
/// fuse_maps(dst, msg, rule, unknown) (dst is "a"), but with work proportional to the
/// message where the policy allows it: with UnknownPolicy::Copy, voxels only `dst` knows are
/// not visited. The information loss of every fused voxel is added into `loss` (in place;
/// may be null). Requires compatible maps (check_compatible()). With `threads` > 1, disjoint
/// subtrees are fused on up to that many threads (the caller's included), with the same
/// result as on one; an exception on a worker reaches the caller.
FuseIntoStats fuse_into(OccupancyMap& dst, const OccupancyMap& msg, Rule rule,
                        UnknownPolicy unknown, ScalarTree* loss, unsigned threads = 1);

/// A simultaneous bidirectional exchange: fuses b into a and a into b at once, in place,
/// each with its own map as "a" of the rule; equal to fuse_into(a, b_before) and
/// fuse_into(b, a_before), without copying either map. Returns the stats of a and of b.
std::pair<FuseIntoStats, FuseIntoStats> fuse_mutual(OccupancyMap& a, OccupancyMap& b, Rule rule,
                                                    UnknownPolicy unknown, ScalarTree* loss_a,
                                                    ScalarTree* loss_b);

/// `dst -= msg` voxel by voxel in log-odds, in place: naive-Bayes fusion (unknown voxels
/// copied) of `msg` with its values negated as they are read, so the same tree and bits as
/// fuse_into(dst, negated copy of msg) without the copy. Clamps to dst's thresholds (the
/// channel filter's maps have them open). Requires compatible maps.
void subtract_into(OccupancyMap& dst, const OccupancyMap& msg);

/// Adds the scalar tree `b` into `acc` voxel by voxel (a coarse leaf of either stands for
/// the voxels below it; voxels only in b are added to acc). Accumulates information loss.
void accumulate_loss(ScalarTree& acc, const ScalarTree& b);

}  // namespace octofuse
