// octofuse: rigid transforms and resampling of occupancy maps onto another voxel grid.
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <memory>

namespace octofuse {

/// Counts of one resampling (how much work it was and what it produced).
struct TransformStats {
  std::size_t source_leaves = 0;  ///< leaves of the source map
  std::size_t samples = 0;        ///< sample points mapped through the transform
  std::size_t target_voxels = 0;  ///< finest target voxels that received a value
};

/// How a target voxel gets its value from the source cells whose centres land in it.
enum class Resampling {
  Vote,     ///< occupied wins (the largest vote if any is occupied), else the mean of the votes
  Nearest,  ///< the value at the pre-image of the voxel's centre (point sampling)
};

/// A new map holding `src` moved by the rigid transform `T` (4x4, row-major; a point p of the
/// source frame goes to T p in the target frame) on a grid of voxel size `resolution`, with the
/// sensor model and clamping of `src`.
///
/// Rule (forward splatting, "occupied wins, then mean"). Every leaf of `src` is cut into cubic
/// cells of edge h = min(source resolution, `resolution`) / 2 (edge h = resolution when the
/// transform maps the grid onto itself: equal resolutions, a rotation that permutes the axes
/// and a translation by whole voxels); the centre of each cell is mapped through T and votes
/// with the leaf's log-odds in the target voxel it lands in. A target voxel with at least one
/// vote gets: the largest vote if any vote is occupied (log-odds > 0), otherwise the mean of
/// its votes (every cell has the same volume, so this is the volume-weighted mean of the free
/// evidence it overlaps). Unknown source space casts no votes. Consequences: the identity, a
/// translation by whole voxels and rotations by multiples of 90 degrees about the axes are
/// exact; a target voxel touching an occupied source voxel is occupied; a target voxel exists
/// only where some source cell centre landed (no voxel far from the source's known space); a
/// cell edge of at most half a target voxel leaves no target voxel that lies inside the
/// transformed known space without a vote.
///
/// T must be rigid (the caller checks); throws std::invalid_argument if the transformed map
/// leaves the octree's key range at `resolution`.
///
/// With Resampling::Nearest a target voxel instead takes the value of the source cell that holds
/// the pre-image of its centre (point sampling), and stays unknown where that pre-image is in
/// unknown space. Surfaces keep their thickness and known space does not grow, so maps moved back
/// and forth between frames (messages between agents) do not thicken at every move; the exact
/// cases above stay exact.
std::unique_ptr<OccupancyMap> transform_map(const OccupancyMap& src, const double T[16],
                                            double resolution,
                                            Resampling resampling = Resampling::Vote,
                                            TransformStats* stats = nullptr);

}  // namespace octofuse
