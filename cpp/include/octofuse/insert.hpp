// octofuse: scan insertion that computes each scan's ray keys once, in parallel, and applies
// them to several maps at once (an agent's map and the centralized map).
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <octomap/OcTreeKey.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace octofuse {

/// One scan to insert: points in the sensor frame, its sensor-to-map pose and its targets.
struct ScanInput {
  const void* xyz = nullptr;  ///< n x 3 points, float or double (see is_double)
  bool is_double = true;
  std::size_t n = 0;
  double pose[16];  ///< row-major 4x4 sensor-to-map transform
  double max_range = -1.0;
  std::vector<OccupancyMap*> targets;  ///< maps this scan updates (all of equal resolution)
  /// true: the points are in the map frame and only the translation of `pose` is used (the
  /// sensor origin), as OccupancyMap::insert_scan() takes a scan
  bool map_frame = false;
};

struct FastInsert;  // insert_fast.hpp
struct FastScan;

/// Most threads insert_batch() takes.
inline constexpr unsigned kMaxThreads = 256;

/// The machine's hardware threads, within 1..kMaxThreads: the default thread count.
unsigned default_threads();

/// The update of each scan of a batch, traced once on a grid, to apply to any maps of that
/// grid (items in ascending code order, as OctoMap's computeUpdate() would update).
struct RayItems {
  double resolution = 0.0;                           ///< the grid's voxel size
  std::vector<std::vector<std::uint64_t>> per_scan;  ///< one scan's items each
  /// the fast mode (insert_fast.hpp): each scan traced (per_scan's items then empty)
  std::vector<std::shared_ptr<const FastScan>> fast;
};

/// Traces the rays of `scans` on `grid`'s grid, scans in parallel on `threads` threads (with
/// `targeted_only`, a scan without targets is skipped: no items). Every scan is checked
/// (ScanCheck) first: throws std::invalid_argument naming the scan and point row if a ray
/// cannot be traced, or if threads is not in 1..kMaxThreads. With `fast`, the items of
/// the fast mode (insert_fast.hpp), which apply_rays() applies scan by scan.
RayItems trace_rays(const std::vector<ScanInput>& scans, const OccupancyMap& grid, unsigned threads,
                    bool targeted_only = false, const FastInsert* fast = nullptr);

/// Applies `items.per_scan[i]` to every map of `targets[i]`: each map receives its scans in
/// batch order, several in one walk of its tree (a voxel's updates in scan order: the same
/// tree as scan after scan), different maps in parallel (the most work first). The maps must
/// be on the items' grid (the caller checks). An exception of a worker thread (std::bad_alloc)
/// is rethrown on the calling thread; the maps may then hold part of the batch.
void apply_rays(const RayItems& items, const std::vector<std::vector<OccupancyMap*>>& targets,
                unsigned threads);

/// Inserts a batch of scans: trace_rays() on the grid of the scans' targets, then
/// apply_rays() to the targets. The result equals inserting each scan with
/// insertPointCloud() into each of its targets (with `fast`: the fast mode). Exceptions as in
/// those two.
void insert_batch(const std::vector<ScanInput>& scans, unsigned threads,
                  const FastInsert* fast = nullptr);

/// One scan in the map frame into one map by the depth-first batch path of insert_batch():
/// the same map as OccupancyMap::insert_scan() (OctoMap's insertPointCloud), with the same
/// checks and messages (std::invalid_argument naming the point row; no change then).
template <class Real>
void insert_scan_batched(OccupancyMap& map, const Real* xyz, std::size_t n, const double origin[3],
                         double max_range);

}  // namespace octofuse
