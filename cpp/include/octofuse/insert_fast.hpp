// octofuse: real-time scan insertion ("fast" mode) for dense 3D lidar scans.
//
// The exact mode (insert.hpp) updates every voxel of every ray, as OctoMap's insertPointCloud:
// a 40 m ray at 0.1 m crosses 400-700 voxels, which the ray's neighbours mostly cross too.
// The fast mode keeps OctoMap's update rules (a hit +log(p_hit / (1 - p_hit)) on every end
// point's voxel, a miss on the free voxels of the rays, each voxel updated once per scan,
// end points winning over free, clamping) but clears free space a coarse cell at a time
// where the scan's rays are dense, and traces one ray per voxel where rays cut at the
// maximum range end:
//
//  * rays cut at the maximum range that end in one voxel (the returns of one beam past the
//    range, neighbouring beams) are one ray, the one to the least end there (by x, then y,
//    then z);
//  * the space is cut into cells of 2^L voxels per edge (L = coarse_levels, an octree level);
//  * a cell is cleared whole (every voxel under it gets one miss, as one node of the tree) if
//    at least `min_rays` rays of the scan cross it and none of the scan's end points lies in
//    it; every other cell gets exactly the voxels that the exact mode gives it (OctoMap's
//    voxel walk, run on without a break through consecutive such cells);
//  * a cell where the map already holds an occupied voxel is not cleared whole but gets the
//    exact mode's voxels (found when the scan is applied: its rays are traced again there).
//
// So the fast map differs from the exact one in cleared cells, which held no occupied voxel:
// voxels there between the rays become free (the exact mode leaves them unknown), and a
// voxel hit later starts from that miss; and elsewhere by the voxels that only the other
// cut rays to an end voxel cross (left unknown). A scan whose every cell is crossed by fewer
// than min_rays rays and whose cut rays end in voxels of their own (a single ray) gives the
// exact map.
// tests/python/test_insert_fast.py states the bound on real lidar clouds.
#pragma once

#include "octofuse/insert.hpp"
#include "octofuse/occupancy_map.hpp"

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace octofuse {

/// How scans update a map: OctoMap's insertPointCloud voxel for voxel, or the fast mode.
enum class InsertMode { Exact, Fast };

/// Parses "exact" or "fast"; std::invalid_argument otherwise.
InsertMode parse_insert_mode(const std::string& name);

/// Parameters of the fast mode (see above).
struct FastInsert {
  unsigned coarse_levels = 3;  ///< a cleared cell has 2^L voxels per edge (1 to 8)
  unsigned min_rays = 8;       ///< rays that must cross a cell to clear it whole (>= 1)
  unsigned threads = 1;        ///< threads tracing one scan (1 to kMaxThreads)

  /// Throws std::invalid_argument naming a value out of range.
  void validate() const;
};

/// One map-frame scan traced for the fast mode, to apply to any maps of its grid.
struct FastScan {
  std::vector<float> ends;  ///< the ends of the rays to trace (cut to the maximum range), x y z
                            ///< (one per end voxel of the cut ones), in the order of their codes
  float origin[3] = {0, 0, 0};       ///< the sensor
  unsigned levels = 0;               ///< FastInsert::coarse_levels
  unsigned threads = 1;              ///< FastInsert::threads
  std::vector<std::uint64_t> cells;  ///< the cells cleared whole (cell codes, ascending)
  /// the update: items in ascending code order (the codes and hit flag of key_codes.hpp, and
  /// cells: the code of their first voxel with bit 62 set)
  std::vector<std::uint64_t> items;
};

/// Traces a map-frame scan for the fast mode. Every ray is checked first (ScanCheck;
/// std::invalid_argument prefixed by `where`; and for options out of range). With `map` (the
/// map the scan goes into, not changed while this runs), cells where it holds occupied
/// voxels are traced voxel by voxel at once, so that applying the scan to it needs no second
/// walk; and so are the cells for which `blocked(cell code)` is true.
FastScan trace_fast(const OccupancyTree& grid, const float* xyz, std::size_t n,
                    const float origin[3], double max_range, const FastInsert& opt,
                    const std::string& where, const OccupancyTree* map = nullptr,
                    const std::function<bool(std::uint64_t)>& blocked = {});

/// One scan of a batch for trace_fast_batch().
struct FastInput {
  std::vector<float> pts;  ///< map-frame points, x y z
  float origin[3] = {0, 0, 0};
  double max_range = -1.0;
  const OccupancyTree* map = nullptr;  ///< trace_fast()'s `map` (not changed meanwhile)
  std::string where;                   ///< prefix of error messages
  bool skip = true;                    ///< no scan here (no result)
};

/// Traces a batch of scans for the fast mode, in parallel on `threads` threads (all checked
/// before the result is returned). A scan's cells where an earlier scan of the batch has an
/// end point are traced voxel by voxel (the occupied voxels it leaves), so that applying the
/// batch in order needs no second walk for them.
std::vector<std::shared_ptr<const FastScan>> trace_fast_batch(const OccupancyTree& grid,
                                                              const std::vector<FastInput>& in,
                                                              const FastInsert& opt,
                                                              unsigned threads);

/// Applies a traced scan to a map in one walk of its tree; a cell where the map holds an
/// occupied voxel is left out of it and gets the exact mode's voxels in a second walk (its
/// rays traced again). A map with change detection is refused (std::invalid_argument).
void apply_fast(OccupancyMap& map, const FastScan& scan);

/// One map-frame scan into one map in the fast mode (checks as insert_scan_batched()).
template <class Real>
void insert_scan_fast(OccupancyMap& map, const Real* xyz, std::size_t n, const double origin[3],
                      double max_range, const FastInsert& opt);

/// The baseline of a "ray loop": OctoMap's insertRay() for every point (no merging of a
/// scan's voxels; free and occupied updates in ray order). For benchmarks.
void insert_ray_loop(OccupancyMap& map, const float* xyz, std::size_t n, const double origin[3],
                     double max_range);

}  // namespace octofuse
