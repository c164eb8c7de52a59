// octofuse: OctoMap's ".ot" (full) and ".bt" (binary, maximum likelihood) map files.
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <memory>
#include <string>

namespace octofuse {

/// Reads a ".ot" or ".bt" file (told apart by its first line, not its name). Everything the
/// file declares is checked before the tree is allocated: only regular files are opened (no
/// FIFOs or devices); the header must name an OcTree with a valid resolution and, if given, a
/// node count the data can hold; the whole tree structure is parsed once without allocating
/// (truncation, depth, non-finite values), and a tree that would need more than half of the
/// machine's memory is refused. Throws MapFileError naming the file and the offending value;
/// bytes quoted from the file are escaped, so messages are always valid UTF-8.
std::unique_ptr<OccupancyMap> read_map_file(const std::string& path);

/// Writes `map` to `path`: ".bt" as OctoMap's maximum-likelihood binary (probabilities are
/// lost), anything else in the full ".ot" format, both with octofuse's sensor model in a
/// header comment. Written to a temporary file and renamed. Throws MapFileError.
void write_map_file(const OccupancyMap& map, const std::string& path);

/// Reads a whole ".ot" or ".bt" stream held in memory with the checks of read_map_file();
/// messages name the stream `name`.
std::unique_ptr<OccupancyMap> read_map_stream(const std::string& bytes, const std::string& name);

/// The bytes write_map_file() writes (header and tree data), without a file.
std::string write_map_stream(const OccupancyMap& map, bool binary = false);

/// OctoMap's node data alone (OcTree::writeData: value and child mask per node, depth
/// first), as octomap_msgs' fullMapToMsg puts it in an octomap_msgs/Octomap message; empty for
/// an empty map.
std::string write_tree_data(const OccupancyMap& map);

/// A map from node data as write_tree_data() writes it, with the resolution, sensor model and
/// clamping of `params`; checked like read_map_file() (MapFileError naming `name`).
std::unique_ptr<OccupancyMap> read_tree_data(const std::string& data, const MapParams& params,
                                             const std::string& name);

}  // namespace octofuse
