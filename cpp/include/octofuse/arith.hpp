// octofuse: log-odds arithmetic on whole maps, for exact fusion (channel filters): unclamped
// storage, negation, clamping for output, and voxel values replaced from a message.
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <cstddef>
#include <memory>

namespace octofuse {

/// Opens the map's clamping: its thresholds become -inf and +inf log-odds, so insertion and
/// fusion add log-odds without ever saturating. A copy of the map (OccupancyMap's copy
/// constructor) gets the thresholds of its parameters again; open it again after copying.
void open_clamping(OccupancyMap& map);

/// Every stored log-odds l becomes -l (inner nodes are then recomputed as OctoMap's maximum
/// of their children). With open clamping, fusing the negated map with naive Bayes subtracts.
void negate_values(OccupancyMap& map);

/// Clamps every stored value to the map's current clamping thresholds, then recomputes the
/// inner nodes and prunes. A copy of an opened map has its parameters' thresholds again, so
/// copy + clamp_values gives the map that scoring and files expect.
void clamp_values(OccupancyMap& map);

/// A copy of `map` clamped to its parameters' thresholds: node for node what copy +
/// clamp_values gives (OctoMap's prune() included, which stops at the first level where it
/// prunes nothing), built without the nodes pruning would delete.
std::unique_ptr<OccupancyMap> clamped_copy(const OccupancyMap& map);

/// For every voxel of `msg` (a coarse leaf stands for all its voxels): map += msg - channel,
/// then channel = msg, both at that voxel (a voxel `channel` does not know counts as 0). This
/// replaces the sender's previous contribution by its new one; applying the same message
/// twice changes nothing. Returns the number of voxels set. Maps must be compatible.
std::size_t assign_values(OccupancyMap& map, OccupancyMap& channel, const OccupancyMap& msg);

}  // namespace octofuse
