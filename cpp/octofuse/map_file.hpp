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

}  // namespace octofuse
