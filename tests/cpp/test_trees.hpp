// Trees for the tests: random maps and their finest-level expansion.
#pragma once

#include "octofuse/occupancy_map.hpp"

#include <map>
#include <random>
#include <tuple>

namespace octofuse_test {

using octofuse::MapParams;
using octofuse::OccupancyMap;
using octofuse::OccupancyTree;

using Key = std::tuple<unsigned, unsigned, unsigned>;

// Every finest-level voxel of a tree with its value (a coarse leaf stands for all below it).
template <class Tree>
std::map<Key, float> expand(const Tree& t) {
  std::map<Key, float> out;
  for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) {
    const unsigned span = 1u << (16 - it.getDepth());
    octomap::OcTreeKey k = it.getKey();
    unsigned k0[3];
    for (int a = 0; a < 3; ++a) k0[a] = k[a] & ~(span - 1);
    for (unsigned x = 0; x < span; ++x)
      for (unsigned y = 0; y < span; ++y)
        for (unsigned z = 0; z < span; ++z) out[{k0[0] + x, k0[1] + y, k0[2] + z}] = it->getValue();
  }
  return out;
}

// A random tree over a 16^3 voxel block with some coarse (pruned) blocks.
inline OccupancyMap random_map(unsigned seed, double coarse_fraction) {
  OccupancyMap m(MapParams{});
  OccupancyTree& t = m.settled_tree();
  std::mt19937 rng(seed);
  const float values[] = {-2.0f, -1.0f, -0.4f, 0.4f, 0.85f, 2.0f, 3.5f};
  std::uniform_int_distribution<int> v(0, 6), c(0, 15), coin(0, 99);
  const unsigned base = 32768 - 8;
  for (int i = 0; i < 600; ++i) {
    octomap::OcTreeKey k(base + c(rng), base + c(rng), base + c(rng));
    t.setNodeValue(k, values[v(rng)], true);
  }
  for (int i = 0; i < 6; ++i) {  // uniform 4x4x4 blocks prune to depth-14 leaves
    if (coin(rng) >= coarse_fraction * 100) continue;
    const unsigned bx = base + 4 * (c(rng) / 4), by = base + 4 * (c(rng) / 4),
                   bz = base + 4 * (c(rng) / 4);
    const float val = values[v(rng)];
    for (unsigned x = 0; x < 4; ++x)
      for (unsigned y = 0; y < 4; ++y)
        for (unsigned z = 0; z < 4; ++z)
          t.setNodeValue(octomap::OcTreeKey(bx + x, by + y, bz + z), val, true);
  }
  t.updateInnerOccupancy();
  t.prune();
  return m;
}

// A map of n^3 finest voxels with distinct values (no pruning): about 1.15 n^3 nodes.
inline OccupancyMap dense_map(unsigned n) {
  OccupancyMap m(MapParams{});
  OccupancyTree& t = m.settled_tree();
  for (unsigned x = 0; x < n; ++x)
    for (unsigned y = 0; y < n; ++y)
      for (unsigned z = 0; z < n; ++z)
        t.setNodeValue(octomap::OcTreeKey(32768 + x, 32768 + y, 32768 + z),
                       0.01f * static_cast<float>((x * 7 + y * 13 + z) % 300) - 1.5f, true);
  return m;
}

}  // namespace octofuse_test
