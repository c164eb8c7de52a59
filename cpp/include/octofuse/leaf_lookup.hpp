// octofuse: the leaves of a map with the value a scalar tree holds at their centres (the
// voxels a heat map shows with their information loss), and a scalar tree's values alone.
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <cstdint>
#include <vector>

namespace octofuse {

/// The leaves of `map` of class `which` (in OctoMap's leaf order) for which a leaf of `scalar`
/// contains the leaf's centre, and that leaf's value in `scalar_values`. The containing leaf
/// is found depth by depth from the centre's coordinates (the cell floor(centre / size) at
/// each depth the scalar tree has leaves at, sizes from the map's resolution), which is what the
/// Python lookup (octofuse.maps.infoloss.Leaves.values_at) computes, value for value.
LeafArrays leaves_with_values(const OccupancyMap& map, const ScalarTree& scalar, LeafClass which,
                              std::vector<float>& scalar_values);

/// A scalar tree's leaf values and depths (in OctoMap's leaf order), without their geometry.
void scalar_values_and_depths(const ScalarTree& tree, std::vector<float>& values,
                              std::vector<std::uint8_t>& depths);

}  // namespace octofuse
