// octofuse: applying a fast-mode scan's items to a tree (insert_fast.cpp), on one or more
// threads.
#pragma once

#include "octofuse/tree.hpp"

#include <cstdint>
#include <vector>

namespace octofuse::detail {

/// An item that stands for a whole cell (the code of its first voxel); never with kHit.
inline constexpr std::uint64_t kCell = 1ULL << 62;
/// The code of an item, without its flags.
inline constexpr std::uint64_t kCodeOnly = kCell - 1;

/// Applies a fast scan's items (ascending codes, one per voxel or per cell of 2^`level`
/// voxels per edge; key_codes.hpp's hit flag, kCell) to `tree`, on up to `threads` threads
/// (every node ends as on one thread). Returns the cells left out because the tree holds
/// occupied voxels in them (cell codes, ascending, each once).
std::vector<std::uint64_t> apply_fast_items(OccupancyTree& tree, unsigned level,
                                            const std::uint64_t* b, const std::uint64_t* e,
                                            unsigned threads);

}  // namespace octofuse::detail
