// octofuse: the one adapter around octomap::OcTree (insertion, file I/O, leaf export).
#pragma once

#include <octomap/OcTree.h>
#include <octomap/OcTreeBase.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace octofuse {

/// Error raised for unreadable, truncated or foreign map files; the message names the file.
class MapFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Sensor model and clamping of an occupancy map, as probabilities.
struct MapParams {
  double resolution = 0.05;    ///< edge length of the finest voxel in metres
  double prob_hit = 0.7;       ///< P(occupied | hit)
  double prob_miss = 0.4;      ///< P(occupied | ray passed through)
  double clamp_min = 0.1192;   ///< lower clamping threshold (probability)
  double clamp_max = 0.971;    ///< upper clamping threshold (probability)

  /// Throws std::invalid_argument naming the offending value if the parameters are unusable.
  void validate() const;
};

/// Leaves of a tree as flat arrays (structure of arrays).
struct LeafArrays {
  std::vector<double> centers;  ///< 3 * n, x y z interleaved
  std::vector<double> sizes;    ///< n, edge length in metres
  std::vector<float> values;    ///< n, stored value (log-odds for occupancy maps)
  std::vector<std::uint8_t> depths;  ///< n, tree depth of the leaf (16 = finest)
};

/// An OctoMap occupancy tree with octofuse's parameters; owns its octomap::OcTree.
class OccupancyMap {
 public:
  explicit OccupancyMap(const MapParams& params);

  /// Deep copy (all nodes).
  OccupancyMap(const OccupancyMap& other);
  OccupancyMap& operator=(const OccupancyMap&) = delete;

  /// Inserts one scan with OctoMap's ray casting update (octomap::OcTree::insertPointCloud).
  /// `xyz` holds n points (x y z interleaved) in the map frame; rays longer than max_range
  /// (if > 0) clear free space up to max_range only. Inner nodes are updated.
  template <class Real>
  void insert_scan(const Real* xyz, std::size_t n, const double origin[3], double max_range);

  /// Same as insert_scan() for points given in the sensor frame: `pose` is the 4x4
  /// row-major sensor-to-map transform; the sensor origin is its translation.
  template <class Real>
  void insert_scan_from_sensor(const Real* xyz, std::size_t n, const double pose[16],
                               double max_range);

  /// Writes the map: ".bt" writes OctoMap's maximum-likelihood binary (probabilities are
  /// lost), anything else the full ".ot" format. Written to a temporary file first and
  /// renamed, so an existing file is never left half-written. Throws MapFileError.
  void save(const std::string& path) const;

  /// Reads a ".ot" (OcTree) or ".bt" file after validating its structure. Throws
  /// MapFileError naming the file for missing, truncated or foreign files.
  static std::unique_ptr<OccupancyMap> load(const std::string& path);

  /// Leaf centres, sizes and log-odds.
  LeafArrays leaves() const;

  const MapParams& params() const { return params_; }
  std::size_t num_leaves() const { return tree_->getNumLeafNodes(); }
  std::size_t num_nodes() const { return tree_->size(); }
  std::size_t memory_bytes() const { return tree_->memoryUsage(); }
  octomap::OcTree& tree() { return *tree_; }
  const octomap::OcTree& tree() const { return *tree_; }

  /// Clamping thresholds as the float log-odds OctoMap stores.
  float clamp_min_logodds() const { return tree_->getClampingThresMinLog(); }
  float clamp_max_logodds() const { return tree_->getClampingThresMaxLog(); }

 private:
  MapParams params_;
  std::unique_ptr<octomap::OcTree> tree_;
};

/// Per-voxel scalar tree (e.g. the information loss of a fusion), same key grid as the maps.
using ScalarTree = octomap::OcTreeBase<octomap::OcTreeDataNode<float>>;

/// Leaves of a scalar tree.
LeafArrays scalar_leaves(const ScalarTree& tree);


}  // namespace octofuse
